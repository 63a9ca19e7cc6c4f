//! Pixels bucketed in 16-pixel cells for radius search: the keypoints of a
//! frame (tracking's search by projection) or of a keyframe (fusion).

/// Keypoints bucketed by undistorted position, for radius search.
#[derive(Clone)]
pub struct Grid {
    cell: f64,
    cols: usize,
    rows: usize,
    cells: Vec<Vec<usize>>,
}

impl Grid {
    /// The grid of undistorted keypoints `un` in a `width x height` image.
    pub fn new(un: &[(f64, f64)], width: usize, height: usize) -> Self {
        let cell = 16.0;
        let (cols, rows) = (width.div_ceil(16) + 2, height.div_ceil(16) + 2);
        let mut cells = vec![Vec::new(); cols * rows];
        for (i, &(u, v)) in un.iter().enumerate() {
            if let Some(c) = Self::index(cell, cols, rows, u, v) {
                cells[c].push(i);
            }
        }
        Self {
            cell,
            cols,
            rows,
            cells,
        }
    }

    fn index(cell: f64, cols: usize, rows: usize, u: f64, v: f64) -> Option<usize> {
        let (cx, cy) = ((u / cell).floor() + 1.0, (v / cell).floor() + 1.0);
        (cx >= 0.0 && cy >= 0.0 && (cx as usize) < cols && (cy as usize) < rows)
            .then(|| cy as usize * cols + cx as usize)
    }

    /// Indices of the pixels within `r` of (u, v) (a square: callers check
    /// the distance), into `out`.
    pub fn near(&self, u: f64, v: f64, r: f64, out: &mut Vec<usize>) {
        out.clear();
        for cell in self.cells_near(u, v, r) {
            out.extend_from_slice(cell);
        }
    }

    /// [`Self::near`] cell by cell, without copying the indices (for a
    /// caller that visits many of them once).
    pub fn cells_near(&self, u: f64, v: f64, r: f64) -> impl Iterator<Item = &[usize]> {
        let (xs, ys) = self.span(u, v, r);
        ys.flat_map(move |cy| {
            xs.clone()
                .map(move |cx| self.cells[cy * self.cols + cx].as_slice())
        })
    }

    /// The columns and rows of the cells within `r` of (u, v).
    fn span(
        &self,
        u: f64,
        v: f64,
        r: f64,
    ) -> (
        std::ops::RangeInclusive<usize>,
        std::ops::RangeInclusive<usize>,
    ) {
        let (x0, x1) = (
            ((u - r) / self.cell).floor() + 1.0,
            ((u + r) / self.cell).floor() + 1.0,
        );
        let (y0, y1) = (
            ((v - r) / self.cell).floor() + 1.0,
            ((v + r) / self.cell).floor() + 1.0,
        );
        (
            x0.max(0.0) as usize..=(x1.max(0.0) as usize).min(self.cols - 1),
            y0.max(0.0) as usize..=(y1.max(0.0) as usize).min(self.rows - 1),
        )
    }

    /// The indices in cell order (cells row by row) and where each cell
    /// starts in that order (one entry more than cells): for a caller that
    /// copies its items in this order, [`Self::rows_near`] gives the cells
    /// near a point as one contiguous range per row of cells.
    pub fn cell_order(&self) -> (Vec<usize>, Vec<usize>) {
        let mut order = Vec::with_capacity(self.cells.iter().map(Vec::len).sum());
        let mut starts = Vec::with_capacity(self.cells.len() + 1);
        for cell in &self.cells {
            starts.push(order.len());
            order.extend_from_slice(cell);
        }
        starts.push(order.len());
        (order, starts)
    }

    /// The cells within `r` of (u, v) (the square of [`Self::near`]) as
    /// ranges of [`Self::cell_order`]'s order, one per row of cells.
    pub fn rows_near<'a>(
        &self,
        starts: &'a [usize],
        u: f64,
        v: f64,
        r: f64,
    ) -> impl Iterator<Item = std::ops::Range<usize>> + 'a {
        assert_eq!(starts.len(), self.cells.len() + 1, "starts of another grid");
        let (xs, ys) = self.span(u, v, r);
        let cols = self.cols;
        // A square beyond the right border has start > end: empty runs.
        let (x1, x0) = (xs.end() + 1, (*xs.start()).min(xs.end() + 1));
        ys.map(move |cy| starts[cy * cols + x0]..starts[cy * cols + x1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_near_cover_the_same_points_as_near() {
        let mut rng = crate::rng::SplitMix64::new(5);
        let points: Vec<(f64, f64)> = (0..500)
            .map(|_| (rng.uniform(-10.0, 650.0), rng.uniform(-10.0, 490.0)))
            .collect();
        let grid = Grid::new(&points, 640, 480);
        let (order, starts) = grid.cell_order();
        let mut near = Vec::new();
        for (u, v, r) in [
            (320.0, 240.0, 40.0),
            (5.0, 5.0, 120.0),
            (630.0, 470.0, 17.0),
            (-50.0, 0.0, 30.0),
            (900.0, 600.0, 40.0),
            (900.0, 200.0, 40.0),
        ] {
            grid.near(u, v, r, &mut near);
            let mut by_rows: Vec<usize> = grid
                .rows_near(&starts, u, v, r)
                .flat_map(|range| order[range].to_vec())
                .collect();
            near.sort_unstable();
            by_rows.sort_unstable();
            assert_eq!(by_rows, near, "({u}, {v}) r {r}");
        }
    }
}
