/// A discrete distribution over `0..n` proportional to non-negative weights, sampled by inverting its
/// CDF with a binary search. Used to choose lights in proportion to their power.
#[derive(Clone, Debug, Default)]
pub struct Distribution1D {
    /// cdf[i] = Σ_{j<i} w_j / W, with cdf[0] = 0 and cdf[n] = 1.
    cdf: Vec<f32>,
    weights: Vec<f32>,
    /// pmf[i] = w_i / W rounded to f32, computed once (it is asked for on every light sample).
    pmf: Vec<f32>,
    total: f64,
}

impl Distribution1D {
    /// Builds the distribution. Negative or non-finite weights count as zero. If every weight is
    /// zero the distribution is empty ([`Distribution1D::is_empty`]) and must not be sampled.
    pub fn new(weights: &[f32]) -> Self {
        let weights: Vec<f32> = weights
            .iter()
            .map(|&w| if w.is_finite() && w > 0.0 { w } else { 0.0 })
            .collect();
        let total: f64 = weights.iter().map(|&w| w as f64).sum();
        let mut cdf = Vec::with_capacity(weights.len() + 1);
        let mut acc = 0.0f64;
        cdf.push(0.0);
        for &w in &weights {
            acc += w as f64;
            cdf.push(if total > 0.0 {
                (acc / total) as f32
            } else {
                0.0
            });
        }
        if total > 0.0 {
            if let Some(last) = cdf.last_mut() {
                *last = 1.0;
            }
        }
        let pmf = weights
            .iter()
            .map(|&w| {
                if total > 0.0 {
                    (w as f64 / total) as f32
                } else {
                    0.0
                }
            })
            .collect();
        Distribution1D {
            cdf,
            weights,
            pmf,
            total,
        }
    }

    /// Number of outcomes (including zero-weight ones).
    pub fn len(&self) -> usize {
        self.weights.len()
    }

    /// The CDF: `len() + 1` values from 0 to 1.
    pub(crate) fn cdf(&self) -> &[f32] {
        &self.cdf
    }

    /// The (sanitised) weights.
    pub(crate) fn weights(&self) -> &[f32] {
        &self.weights
    }

    /// True when no outcome has positive weight.
    pub fn is_empty(&self) -> bool {
        self.total <= 0.0
    }

    /// Sum of the weights.
    pub fn total(&self) -> f64 {
        self.total
    }

    /// Probability of outcome `i`.
    #[inline]
    pub fn pmf(&self, i: usize) -> f32 {
        self.pmf[i]
    }

    /// Draws an outcome from u ∈ [0,1). Returns (index, probability, u remapped to [0,1) within the
    /// chosen outcome's CDF interval, so one random number can be reused).
    #[inline]
    pub fn sample(&self, u: f32) -> (usize, f32, f32) {
        let i = self.sample_index(u);
        let lo = self.cdf[i];
        let width = self.cdf[i + 1] - lo;
        let remapped = if width > 0.0 {
            ((u - lo) / width).clamp(0.0, 1.0 - f32::EPSILON / 2.0)
        } else {
            0.0
        };
        (i, self.pmf[i], remapped)
    }

    /// The outcome [`Distribution1D::sample`] draws from `u`, and its probability, without the
    /// remapped value (for callers that do not reuse `u`).
    #[inline]
    pub fn sample_discrete(&self, u: f32) -> (usize, f32) {
        let i = self.sample_index(u);
        (i, self.pmf[i])
    }

    #[inline]
    fn sample_index(&self, u: f32) -> usize {
        // First index whose CDF interval [cdf[i], cdf[i+1]) contains u, skipping zero-width ones.
        let n = self.weights.len();
        let i = self.cdf[1..].partition_point(|&c| c <= u).min(n - 1);
        // Never return a zero-weight outcome (u at an interval's exact upper end after rounding).
        if self.weights[i] > 0.0 {
            i
        } else {
            (0..n)
                .rev()
                .find(|&j| self.weights[j] > 0.0 && self.cdf[j] <= u)
                .unwrap_or(i)
        }
    }
}
