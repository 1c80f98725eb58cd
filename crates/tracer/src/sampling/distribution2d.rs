//! A piecewise-constant density on the unit square, sampled by the inverse-CDF method: a row is
//! chosen from the marginal distribution of the row sums, then a column from that row's
//! conditional distribution, and the point is placed inside the chosen cell by the remainder of
//! each random number, so the sample's density is the cell's weight over the total, times the
//! number of cells. Used to importance-sample environment maps.

use super::Distribution1D;
use glam::Vec2;

#[derive(Clone, Debug, Default)]
pub struct Distribution2D {
    width: usize,
    height: usize,
    /// One distribution over the columns per row.
    conditional: Vec<Distribution1D>,
    /// The distribution over rows, by row sums.
    marginal: Distribution1D,
}

impl Distribution2D {
    /// `weights` row by row, `width` per row (top row first: row `j` covers v ∈ [j/h, (j+1)/h)).
    /// Negative and non-finite weights count as zero. Returns `None` when the shape does not match
    /// or every weight is zero (nothing can be sampled).
    pub fn new(weights: &[f32], width: usize, height: usize) -> Option<Self> {
        if width == 0 || height == 0 || weights.len() != width.checked_mul(height)? {
            return None;
        }
        let conditional: Vec<Distribution1D> = weights
            .chunks_exact(width)
            .map(Distribution1D::new)
            .collect();
        let row_sums: Vec<f32> = conditional.iter().map(|d| d.total() as f32).collect();
        let marginal = Distribution1D::new(&row_sums);
        if marginal.is_empty() {
            return None;
        }
        Some(Distribution2D {
            width,
            height,
            conditional,
            marginal,
        })
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// A point of the unit square drawn from `u` ∈ [0,1)², and its density there (with respect to
    /// area on the square). Never lands in a cell of zero weight.
    #[inline]
    pub fn sample(&self, u: Vec2) -> (Vec2, f32) {
        let (row, p_row, v_in) = self.marginal.sample(u.y);
        let (col, p_col, u_in) = self.conditional[row].sample(u.x);
        let point = Vec2::new(
            (col as f32 + u_in) / self.width as f32,
            (row as f32 + v_in) / self.height as f32,
        );
        // Keep the point inside its cell when the division rounds up to the next edge.
        let point = point.min(Vec2::splat(1.0 - f32::EPSILON / 2.0));
        let density = p_row * p_col * (self.width * self.height) as f32;
        (point, density)
    }

    /// The density at `p` of the unit square (clamped into it).
    #[inline]
    pub fn pdf(&self, p: Vec2) -> f32 {
        let (col, row) = self.cell(p);
        self.marginal.pmf(row) * self.conditional[row].pmf(col) * (self.width * self.height) as f32
    }

    /// The cell that contains `p` (clamped into the square; NaN gives cell 0).
    #[inline]
    pub fn cell(&self, p: Vec2) -> (usize, usize) {
        // `as usize` saturates: negative and NaN give 0.
        let col = ((p.x * self.width as f32) as usize).min(self.width - 1);
        let row = ((p.y * self.height as f32) as usize).min(self.height - 1);
        (col, row)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn densities_follow_the_weights_and_integrate_to_one() {
        let w = [0.0, 1.0, 2.0, 3.0, 0.0, 0.0, 4.0, 0.5, 1.5];
        let d = Distribution2D::new(&w, 3, 3).unwrap();
        let total: f32 = w.iter().sum();
        let mut integral = 0.0;
        for row in 0..3 {
            for col in 0..3 {
                let p = Vec2::new((col as f32 + 0.5) / 3.0, (row as f32 + 0.5) / 3.0);
                let want = w[row * 3 + col] / total * 9.0;
                assert!((d.pdf(p) - want).abs() < 1e-5, "{row} {col}");
                integral += d.pdf(p) / 9.0;
            }
        }
        assert!((integral - 1.0).abs() < 1e-5);
        // Samples land in cells of positive weight, with the density pdf() gives there.
        for i in 0..64 {
            for j in 0..64 {
                let u = Vec2::new((i as f32 + 0.5) / 64.0, (j as f32 + 0.5) / 64.0);
                let (p, pdf) = d.sample(u);
                assert!(p.x >= 0.0 && p.x < 1.0 && p.y >= 0.0 && p.y < 1.0);
                let (col, row) = d.cell(p);
                assert!(w[row * 3 + col] > 0.0, "{p}");
                assert!((pdf - d.pdf(p)).abs() < 1e-5);
            }
        }
        assert!(Distribution2D::new(&[0.0; 4], 2, 2).is_none());
        assert!(Distribution2D::new(&[1.0; 4], 3, 2).is_none());
    }
}
