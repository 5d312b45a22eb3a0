//! How much of the image the board corners cover: distortion is only known where corners were.

use nalgebra::Vector2;

use crate::camera::ImageSize;

/// Corner counts on a coarse grid over the image.
#[derive(Clone, Debug)]
pub struct Coverage {
    pub cols: usize,
    pub rows: usize,
    /// Row-major counts of corners per cell.
    pub counts: Vec<usize>,
}

impl Coverage {
    /// A 12-column grid with square-ish cells.
    pub fn of(views: &[&[Vector2<f64>]], size: ImageSize) -> Self {
        let cols = 12usize;
        let rows = ((cols as f64 * f64::from(size.height) / f64::from(size.width)).round()
            as usize)
            .max(1);
        let mut counts = vec![0; cols * rows];
        let (w, h) = (f64::from(size.width), f64::from(size.height));
        for p in views.iter().flat_map(|v| v.iter()) {
            // Pixel centres run from 0 to w − 1; cells split the image edges (−0.5 .. w − 0.5).
            let c = (((p.x + 0.5) / w) * cols as f64).floor();
            let r = (((p.y + 0.5) / h) * rows as f64).floor();
            if c >= 0.0 && r >= 0.0 && (c as usize) < cols && (r as usize) < rows {
                counts[r as usize * cols + c as usize] += 1;
            }
        }
        Coverage { cols, rows, counts }
    }

    /// Percentage of cells with at least one corner.
    pub fn percent(&self) -> f64 {
        100.0 * self.counts.iter().filter(|&&c| c > 0).count() as f64 / self.counts.len() as f64
    }

    /// The grid as text: `.` for an empty cell, `1`-`9` for a few corners, `#` for ten or more.
    pub fn ascii_map(&self) -> String {
        let mut s = String::new();
        for r in 0..self.rows {
            s.push_str("  |");
            for c in 0..self.cols {
                s.push(match self.counts[r * self.cols + c] {
                    0 => '.',
                    n @ 1..=9 => char::from_digit(n as u32, 10).expect("digit"),
                    _ => '#',
                });
            }
            s.push_str("|\n");
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_corners_per_cell() {
        let size = ImageSize {
            width: 1200,
            height: 900,
        };
        let pts = vec![
            Vector2::new(0.0, 0.0),
            Vector2::new(1199.0, 899.0),
            Vector2::new(1.0, 1.0),
        ];
        let cov = Coverage::of(&[&pts], size);
        assert_eq!((cov.cols, cov.rows), (12, 9));
        assert_eq!(cov.counts[0], 2);
        assert_eq!(cov.counts[12 * 9 - 1], 1);
        assert!((cov.percent() - 200.0 / 108.0).abs() < 1e-12);
        assert!(cov.ascii_map().starts_with("  |2..........."));
    }
}
