//! The map as a PLY point cloud (ASCII, x y z and colour): opens in
//! MeshLab, CloudCompare, Open3D and Blender.

use std::io::Write;
use std::path::Path;

/// One map point: world position (metres) and colour.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColouredPoint {
    /// Position (world frame, metres).
    pub position: [f64; 3],
    /// RGB colour.
    pub colour: [u8; 3],
}

/// Writes `points` to `path` via a temporary file and a rename, so a reader
/// never sees half a map.
pub fn write_ply(path: &Path, points: &[ColouredPoint]) -> std::io::Result<()> {
    let tmp = path.with_extension("ply.tmp");
    let written = write_ply_to(&tmp, points).and_then(|()| std::fs::rename(&tmp, path));
    if written.is_err() {
        // A full disk leaves no half-written temporary behind.
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

fn write_ply_to(tmp: &Path, points: &[ColouredPoint]) -> std::io::Result<()> {
    {
        let mut f = std::io::BufWriter::new(std::fs::File::create(tmp)?);
        write!(
            f,
            "ply\nformat ascii 1.0\ncomment dynslam map (world frame, metres)\n\
             element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
             property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
            points.len()
        )?;
        for p in points {
            let [x, y, z] = p.position;
            let [r, g, b] = p.colour;
            writeln!(f, "{x:.4} {y:.4} {z:.4} {r} {g} {b}")?;
        }
        f.flush()?;
    }
    Ok(())
}

/// Reads back the vertices of a file `write_ply` wrote (tests, reports).
pub fn read_ply(path: &Path) -> Result<Vec<ColouredPoint>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let (head, body) = text
        .split_once("end_header\n")
        .ok_or_else(|| format!("{}: no PLY header", path.display()))?;
    let count: usize = head
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .and_then(|n| n.trim().parse().ok())
        .ok_or_else(|| format!("{}: no vertex count", path.display()))?;
    let points: Vec<ColouredPoint> = body
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            if f.len() != 6 {
                return Err(format!("{}: bad vertex line '{l}'", path.display()));
            }
            let x = |i: usize| {
                f[i].parse::<f64>()
                    .map_err(|e| format!("{}: {e}", path.display()))
            };
            let c = |i: usize| {
                f[i].parse::<u8>()
                    .map_err(|e| format!("{}: {e}", path.display()))
            };
            Ok(ColouredPoint {
                position: [x(0)?, x(1)?, x(2)?],
                colour: [c(3)?, c(4)?, c(5)?],
            })
        })
        .collect::<Result<_, _>>()?;
    if points.len() != count {
        return Err(format!(
            "{}: header announces {count} vertices, found {}",
            path.display(),
            points.len()
        ));
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_round_trip() {
        let path = std::env::temp_dir().join(format!("dynslam-ply-{}.ply", std::process::id()));
        let pts = vec![
            ColouredPoint {
                position: [1.0, -2.5, 0.125],
                colour: [255, 0, 7],
            },
            ColouredPoint {
                position: [0.0, 0.0, 3.0],
                colour: [1, 2, 3],
            },
        ];
        write_ply(&path, &pts).unwrap();
        assert_eq!(read_ply(&path).unwrap(), pts);
        std::fs::remove_file(&path).ok();
    }
}
