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
        let (x0, x1) = (
            ((u - r) / self.cell).floor() + 1.0,
            ((u + r) / self.cell).floor() + 1.0,
        );
        let (y0, y1) = (
            ((v - r) / self.cell).floor() + 1.0,
            ((v + r) / self.cell).floor() + 1.0,
        );
        let xs = x0.max(0.0) as usize..=(x1.max(0.0) as usize).min(self.cols - 1);
        (y0.max(0.0) as usize..=(y1.max(0.0) as usize).min(self.rows - 1)).flat_map(move |cy| {
            xs.clone()
                .map(move |cx| self.cells[cy * self.cols + cx].as_slice())
        })
    }
}
