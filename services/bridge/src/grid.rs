//! The occupancy grid for Nav2: the map's points projected onto the floor
//! plane of the map frame (REP-103: z up).
//!
//! A point between `min_height` and `max_height` above the map's z = 0 is
//! an obstacle where it stands; a cell holding at least `min_points` of
//! them is occupied (100). The cells between a point and the keyframe that
//! observed it first were seen through: free (0), unless occupied; points
//! below `min_height` (the floor) count as seen through too, their own cell
//! included. Points above `max_height` (the ceiling, over the robot) are
//! left out, rays included: a ray to the ceiling passes over obstacles. The
//! rest is unknown (-1). ORB-SLAM2's map has no free space of its own, so
//! this is the usual projection of a sparse visual map (as in the
//! occupancy-grid forks of ORB-SLAM2), not a laser scan's.

/// How the grid is made (`[bridge] grid_*`).
#[derive(Debug, Clone, Copy)]
pub struct GridParams {
    /// Metres per cell.
    pub resolution: f64,
    /// Points lower than this above the floor (metres) are not obstacles.
    pub min_height: f64,
    /// Points higher than this (metres) are not obstacles.
    pub max_height: f64,
    /// Points a cell needs to be occupied.
    pub min_points: u32,
    /// A grid wider or longer than this many cells is cut around the
    /// keyframes (a stray far point must not make a huge message).
    pub max_side: usize,
}

/// The grid: `cells` row-major from the cell whose corner is at `origin`
/// (map frame, metres).
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    /// Corner of cell (0, 0) in the map frame (metres).
    pub origin: [f64; 2],
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Cells, row by row: [`UNKNOWN`], [`FREE`] or [`OCCUPIED`].
    pub cells: Vec<i8>,
}

/// A cell nothing was seen through or in.
pub const UNKNOWN: i8 = -1;
/// A cell seen through (between a point and the keyframe that saw it first) or floor.
pub const FREE: i8 = 0;
/// A cell holding at least `min_points` points at obstacle height.
pub const OCCUPIED: i8 = 100;

/// Projects `points` (map frame, each with the index of its keyframe in
/// `keyframes`: the keyframes' camera positions in the map frame). None
/// when nothing falls in the grid's height band.
pub fn project(
    points: &[([f64; 3], usize)],
    keyframes: &[[f64; 3]],
    p: &GridParams,
) -> Option<Grid> {
    let used = |z: f64| z < p.max_height;
    // Bounds: every used point and every keyframe, one cell of margin.
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    let mut grow = |x: f64, y: f64| {
        lo = [lo[0].min(x), lo[1].min(y)];
        hi = [hi[0].max(x), hi[1].max(y)];
    };
    let mut any = false;
    for (q, _) in points.iter().filter(|(q, _)| used(q[2])) {
        grow(q[0], q[1]);
        any = true;
    }
    if !any {
        return None;
    }
    for k in keyframes {
        grow(k[0], k[1]);
    }
    let r = p.resolution;
    let cut = p.max_side as f64 * r;
    // Too large: keep a max_side square around the keyframes' centre.
    for axis in 0..2 {
        if hi[axis] - lo[axis] > cut - 2.0 * r {
            let centre = if keyframes.is_empty() {
                (lo[axis] + hi[axis]) / 2.0
            } else {
                keyframes.iter().map(|k| k[axis]).sum::<f64>() / keyframes.len() as f64
            };
            lo[axis] = centre - cut / 2.0 + r;
            hi[axis] = centre + cut / 2.0 - r;
        }
    }
    let origin = [lo[0] - r, lo[1] - r];
    let width = (((hi[0] - origin[0]) / r).floor() as usize + 2).min(p.max_side);
    let height = (((hi[1] - origin[1]) / r).floor() as usize + 2).min(p.max_side);
    let cell = |x: f64, y: f64| -> Option<(usize, usize)> {
        let (cx, cy) = ((x - origin[0]) / r, (y - origin[1]) / r);
        (cx >= 0.0 && cy >= 0.0 && (cx as usize) < width && (cy as usize) < height)
            .then_some((cx as usize, cy as usize))
    };
    let mut free = vec![false; width * height];
    let mut hits = vec![0u32; width * height];
    for (q, k) in points {
        if !used(q[2]) {
            continue;
        }
        let obstacle = q[2] >= p.min_height;
        let end = cell(q[0], q[1]);
        if let (Some(end), Some(from)) = (end, keyframes.get(*k).and_then(|k| cell(k[0], k[1]))) {
            for (x, y) in line(from, end) {
                if (x, y) != end || !obstacle {
                    free[y * width + x] = true;
                }
            }
        }
        if let (true, Some((x, y))) = (obstacle, end) {
            hits[y * width + x] += 1;
        }
    }
    let cells = hits
        .iter()
        .zip(&free)
        .map(|(&h, &f)| {
            if h >= p.min_points.max(1) {
                OCCUPIED
            } else if f {
                FREE
            } else {
                UNKNOWN
            }
        })
        .collect();
    Some(Grid {
        origin,
        width,
        height,
        cells,
    })
}

/// The cells of a straight line from `a` to `b`, both included
/// (Bresenham).
fn line(a: (usize, usize), b: (usize, usize)) -> impl Iterator<Item = (usize, usize)> {
    let (mut x, mut y) = (a.0 as i64, a.1 as i64);
    let (x1, y1) = (b.0 as i64, b.1 as i64);
    let (dx, dy) = ((x1 - x).abs(), -(y1 - y).abs());
    let (sx, sy) = (if x < x1 { 1 } else { -1 }, if y < y1 { 1 } else { -1 });
    let mut err = dx + dy;
    let mut done = false;
    std::iter::from_fn(move || {
        if done {
            return None;
        }
        let here = (x as usize, y as usize);
        if x == x1 && y == y1 {
            done = true;
        } else {
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
        Some(here)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: GridParams = GridParams {
        resolution: 0.1,
        min_height: 0.1,
        max_height: 1.5,
        min_points: 2,
        max_side: 1000,
    };

    fn at(g: &Grid, x: f64, y: f64) -> i8 {
        let cx = ((x - g.origin[0]) / 0.1) as usize;
        let cy = ((y - g.origin[1]) / 0.1) as usize;
        g.cells[cy * g.width + cx]
    }

    #[test]
    fn a_wall_seen_from_a_keyframe_is_occupied_with_free_space_before_it() {
        // A wall 2 m ahead (x = 2), 0.5 m high, seen from the origin.
        let mut points = Vec::new();
        for i in -5..=5 {
            for h in [0.3, 0.5] {
                points.push(([2.05, i as f64 * 0.1 + 0.05, h], 0));
            }
        }
        // The ceiling above it and a lone point (one is noise).
        points.push(([1.0, 0.05, 2.5], 0));
        points.push(([0.55, -1.05, 0.5], 0));
        let g = project(&points, &[[0.0, 0.0, 0.4]], &P).unwrap();
        assert_eq!(at(&g, 2.05, 0.05), OCCUPIED);
        assert_eq!(at(&g, 2.05, -0.45), OCCUPIED);
        assert_eq!(at(&g, 1.05, 0.05), FREE, "between the camera and the wall");
        assert_eq!(at(&g, 0.55, -1.05), UNKNOWN, "one point is not an obstacle");
        assert_eq!(at(&g, 2.05, -0.85), UNKNOWN, "nothing seen there");
        // Bounds: the wall and the keyframe with a margin.
        assert!(g.origin[0] <= -0.1 + 1e-9 && g.origin[1] <= -1.1);
        assert_eq!(g.cells.len(), g.width * g.height);
    }

    #[test]
    fn floor_points_clear_their_cells_and_nothing_in_the_band_gives_no_grid() {
        let floor = vec![([1.05, 0.05, -0.5], 0), ([1.05, 0.05, 0.0], 0)];
        let g = project(&floor, &[[0.0, 0.0, 0.0]], &P).unwrap();
        assert_eq!(at(&g, 1.05, 0.05), FREE);
        assert!(g.cells.iter().all(|&c| c != OCCUPIED));
        assert!(project(&[([0.0, 0.0, 3.0], 0)], &[[0.0; 3]], &P).is_none());
        assert!(project(&[], &[], &P).is_none());
    }

    #[test]
    fn a_stray_far_point_does_not_make_a_huge_grid() {
        let p = GridParams { max_side: 100, ..P };
        let points = vec![
            ([0.55, 0.55, 0.5], 0),
            ([0.55, 0.55, 0.6], 0),
            ([1e6, -1e6, 0.5], 0),
        ];
        let g = project(&points, &[[0.0; 3]], &p).unwrap();
        assert!(g.width <= 100 && g.height <= 100);
        assert_eq!(at(&g, 0.55, 0.55), OCCUPIED);
    }

    #[test]
    fn lines_cover_both_ends_and_step_one_cell() {
        let cells: Vec<_> = line((0, 0), (3, 1)).collect();
        assert_eq!(cells.first(), Some(&(0, 0)));
        assert_eq!(cells.last(), Some(&(3, 1)));
        assert_eq!(cells.len(), 4);
        assert_eq!(line((2, 2), (2, 2)).count(), 1);
    }
}
