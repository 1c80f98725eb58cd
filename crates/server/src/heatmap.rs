//! Per-pixel heat maps of an accumulation for the dashboard: the sample count (linear scale) and
//! the noise, the relative standard error of each pixel's mean luminance (log scale), coloured with
//! viridis (perceptually uniform, readable by colour-blind users, monotone in lightness).

use pathfarm_tracer::Accumulation;

/// The noise map's fixed scale: 0.1 % … 100 % relative error. Fixed rather than fitted to the
/// image, so that watching it over time shows the noise falling.
pub const NOISE_SCALE: (f64, f64) = (1e-3, 1.0);

/// A heat map: RGB8 pixels and the values at the two ends of the colour scale.
pub struct HeatMap {
    pub rgb: Vec<u8>,
    pub scale: (f64, f64),
}

/// Samples per pixel, from 0 to the largest count in the image.
pub fn samples(acc: &Accumulation) -> HeatMap {
    let scale = samples_scale(acc);
    let rgb = samples_of(acc.pixels.iter().map(|p| p.count), scale.1 as u64);
    HeatMap { rgb, scale }
}

/// The sample map's scale: 0 to the largest per-pixel count.
pub fn samples_scale(acc: &Accumulation) -> (f64, f64) {
    let max = acc.pixels.iter().map(|p| p.count).max().unwrap_or(0);
    (0.0, max as f64)
}

/// The sample map of per-pixel `counts` whose largest is `max`, as RGB8.
pub fn samples_rgb(counts: &[u32], max: u64) -> Vec<u8> {
    samples_of(counts.iter().map(|&c| u64::from(c)), max)
}

fn samples_of(counts: impl Iterator<Item = u64>, max: u64) -> Vec<u8> {
    let max = max as f64;
    counts
        .flat_map(|c| viridis(if max == 0.0 { 0.0 } else { c as f64 / max }))
        .collect()
}

/// Where a pixel falls on the noise map's scale, from the variance of its mean luminance
/// (`None` with fewer than two samples) and its mean luminance.
fn noise_position(var: Option<f64>, lum: f64) -> f64 {
    let (lo, hi) = NOISE_SCALE;
    let (log_lo, log_hi) = (lo.log10(), hi.log10());
    match var {
        None => 1.0,
        Some(var) if var <= 0.0 => 0.0,
        Some(_) if lum <= 0.0 => 1.0,
        Some(var) => {
            let rel = var.sqrt() / lum;
            (rel.log10() - log_lo) / (log_hi - log_lo)
        }
    }
}

fn luminance(m: [f64; 3]) -> f64 {
    0.2126 * m[0] + 0.7152 * m[1] + 0.0722 * m[2]
}

/// The relative standard error √Var[mean] / mean of each pixel's luminance, on [`NOISE_SCALE`]
/// (log). A pixel with fewer than two samples has no estimate and shows as the top of the scale;
/// a black pixel with no variance is exact and shows as the bottom.
pub fn noise(acc: &Accumulation) -> HeatMap {
    let rgb = acc
        .pixels
        .iter()
        .flat_map(|p| viridis(noise_position(p.variance_of_mean(), luminance(p.mean()))))
        .collect();
    HeatMap {
        rgb,
        scale: NOISE_SCALE,
    }
}

/// The noise map (as [`noise`]) of developed pixels: mean RGB, variance of the mean luminance
/// and sample count (`mean` and `variance` are read only where the count is two or more).
pub fn noise_rgb(mean: &[[f32; 3]], variance: &[f32], counts: &[u32]) -> Vec<u8> {
    counts
        .iter()
        .enumerate()
        .flat_map(|(i, &c)| {
            let t = if c < 2 {
                noise_position(None, 0.0)
            } else {
                let m = mean.get(i).copied().unwrap_or_default().map(f64::from);
                let var = variance.get(i).copied().unwrap_or_default();
                noise_position(Some(f64::from(var)), luminance(m))
            };
            viridis(t)
        })
        .collect()
}

/// Viridis, sampled at 9 evenly spaced stops (matplotlib's table) and interpolated linearly;
/// `t` is clamped to [0, 1].
pub fn viridis(t: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 9] = [
        [68.0, 1.0, 84.0],
        [71.0, 44.0, 122.0],
        [59.0, 81.0, 139.0],
        [44.0, 113.0, 142.0],
        [33.0, 144.0, 141.0],
        [39.0, 173.0, 129.0],
        [92.0, 200.0, 99.0],
        [170.0, 220.0, 50.0],
        [253.0, 231.0, 37.0],
    ];
    let t = if t.is_nan() { 1.0 } else { t.clamp(0.0, 1.0) };
    let x = t * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f64;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    [0, 1, 2].map(|c| (a[c] + (b[c] - a[c]) * f).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn viridis_ends_and_clamping() {
        assert_eq!(viridis(0.0), [68, 1, 84]);
        assert_eq!(viridis(1.0), [253, 231, 37]);
        assert_eq!(viridis(-3.0), viridis(0.0));
        assert_eq!(viridis(7.0), viridis(1.0));
        assert_eq!(viridis(f64::NAN), viridis(1.0));
        // Lightness grows along the map.
        let lum = |c: [u8; 3]| 0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64;
        for i in 0..20 {
            assert!(lum(viridis(i as f64 / 20.0)) < lum(viridis((i + 1) as f64 / 20.0)));
        }
    }

    #[test]
    fn sample_map_scales_to_the_largest_count() {
        let mut acc = Accumulation::new(0, 0, 2, 1);
        for _ in 0..4 {
            acc.pixels[1].add_sample(Vec3::ONE);
        }
        acc.pixels[0].add_sample(Vec3::ONE);
        let m = samples(&acc);
        assert_eq!(m.scale, (0.0, 4.0));
        assert_eq!(samples_scale(&acc), (0.0, 4.0));
        assert_eq!(&m.rgb[3..6], &viridis(1.0));
        assert_eq!(&m.rgb[0..3], &viridis(0.25));
    }

    #[test]
    fn noise_map_is_log_scaled_relative_error() {
        let mut acc = Accumulation::new(0, 0, 3, 1);
        // Pixel 0: luminance samples 0.9 and 1.1 → mean 1, sample variance 0.02, Var[mean] 0.01,
        // relative error 0.1 → log position (−1 − (−3)) / 3 = 2/3.
        acc.pixels[0].add_sample(Vec3::splat(0.9));
        acc.pixels[0].add_sample(Vec3::splat(1.1));
        // Pixel 1: one sample, no estimate → top of the scale. Pixel 2: exact black → bottom.
        acc.pixels[1].add_sample(Vec3::ONE);
        acc.pixels[2].add_sample(Vec3::ZERO);
        acc.pixels[2].add_sample(Vec3::ZERO);
        let m = noise(&acc);
        assert_eq!(m.scale, NOISE_SCALE);
        let expect = viridis(2.0 / 3.0);
        for (got, want) in m.rgb[0..3].iter().zip(expect) {
            assert!((*got as i32 - want as i32).abs() <= 1, "{:?}", &m.rgb[0..3]);
        }
        assert_eq!(&m.rgb[3..6], &viridis(1.0));
        assert_eq!(&m.rgb[6..9], &viridis(0.0));
    }
}
