//! Choosing among a few punctual lamps by what each sends to the shading point.
//!
//! A scene exported from Blender typically brings a handful of lamps: a key and a fill point lamp,
//! a spot, a sun. Chosen by power alone, a spot's cone or a lamp behind the surface takes its share
//! of the samples at points it does not light, and a dim lamp near the point gets few. With at
//! most [`MAX_POWER_CHOSEN`] lamps, evaluating each lamp's unshadowed contribution at the point
//! (its light times the BSDF's f · |cos|, as the integrator's light sample would weight it) costs
//! less than the shadow ray the sample then traces, and choosing in proportion to it leaves only
//! the visibility as noise: with one lamp that lights the point, the pick is certain.
//!
//! Unbiased: a lamp's probability is zero only where its contribution is, and every lamp whose
//! contribution is non-zero can be drawn. The weights are luminances of non-negative RGB, zero
//! only for black.
//!
//! [`MAX_POWER_CHOSEN`]: super::MAX_POWER_CHOSEN

use super::{PunctualLight, PunctualSample, MAX_POWER_CHOSEN};
use crate::math::luminance;
use glam::Vec3;

/// The lamp [`choose_by_contribution`] drew: its light at the point, its unshadowed contribution
/// (as the caller's `contribution` gave it) and its probability.
#[derive(Clone, Copy, Debug)]
pub struct ChosenLamp {
    pub index: usize,
    pub sample: PunctualSample,
    pub contribution: Vec3,
    pub pmf: f32,
}

/// Chooses one of `lights` (at most [`MAX_POWER_CHOSEN`]; the caller decides by
/// [`super::chooses_per_point`]) for the point `p`, from `u` in [0, 1), in proportion to the
/// luminance of `contribution(sample)` — what the lamp would add if nothing were in the way. None
/// when no lamp lights `p`.
#[inline]
pub fn choose_by_contribution(
    lights: &[PunctualLight],
    p: Vec3,
    u: f32,
    contribution: impl Fn(&PunctualSample) -> Vec3,
) -> Option<ChosenLamp> {
    debug_assert!(lights.len() <= MAX_POWER_CHOSEN);
    // One pass, each lamp's light and contribution made once (a second pass recomputed the
    // drawn lamp's): lamp k replaces the lamp drawn so far with probability w_k / (the weights
    // up to k), so each is drawn with probability w_k / total in the end. `u` decides every
    // step, rescaled to [0, 1) after each (the part of it the step did not use).
    let mut total = 0.0f32;
    let mut chosen: Option<(usize, PunctualSample, Vec3, f32)> = None;
    let mut u = u;
    for (index, light) in lights.iter().enumerate() {
        let Some(sample) = light.sample_li(p) else {
            continue;
        };
        let contribution = contribution(&sample);
        let w = luminance(contribution);
        // NaN or negative (a BSDF's rounding) lights nothing.
        if !(w > 0.0 && w.is_finite()) {
            continue;
        }
        let take;
        (take, total, u) = draw_step(u, total, w, true);
        if take {
            chosen = Some((index, sample, contribution, w));
        }
    }
    if !(total > 0.0 && total.is_finite()) {
        return None;
    }
    let (index, sample, contribution, w) = chosen?;
    Some(ChosenLamp {
        index,
        sample,
        contribution,
        pmf: w / total,
    })
}

/// One lamp's step of [`choose_by_contribution`]'s running draw: with the weights before it
/// summing to `total` and the draw's value `u`, whether the lamp (of weight `w`; `valid`: one that
/// may be drawn, w > 0 and finite) takes the draw, the new total, and `u` rescaled to what the
/// step left of it. Written without a branch, and shared with the wavefront's lanes
/// (`lanes/lamps.rs`), which make the draw in vector loops with the same bits.
#[inline(always)]
pub(crate) fn draw_step(u: f32, total: f32, w: f32, valid: bool) -> (bool, f32, f32) {
    let total = if valid { total + w } else { total };
    let q = w / total;
    let take = valid && u < q;
    let next = if u < q { u / q } else { (u - q) / (1.0 - q) };
    (take, total, if valid { next.min(ONE_BELOW) } else { u })
}

/// The largest f32 below 1.
const ONE_BELOW: f32 = 1.0 - f32::EPSILON / 2.0;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::light::{DirectionalLight, PointLight, SpotLight};

    /// A floor point lit by a point lamp, a spot pointing at it, a spot pointing away, a point
    /// lamp below the floor, and a sun.
    fn lamps() -> Vec<PunctualLight> {
        vec![
            PunctualLight::Point(PointLight {
                position: Vec3::new(1.0, 0.5, 2.0),
                intensity: Vec3::new(3.0, 2.0, 1.0),
            }),
            PunctualLight::Spot(SpotLight {
                position: Vec3::new(-1.0, 0.0, 3.0),
                direction: Vec3::new(1.0, 0.0, -3.0).normalize(),
                intensity: Vec3::splat(20.0),
                cos_inner: 0.95,
                cos_outer: 0.8,
            }),
            PunctualLight::Spot(SpotLight {
                position: Vec3::new(0.0, 0.0, 3.0),
                direction: Vec3::Z,
                intensity: Vec3::splat(50.0),
                cos_inner: 0.9,
                cos_outer: 0.7,
            }),
            PunctualLight::Point(PointLight {
                position: Vec3::new(0.0, 0.0, -1.0),
                intensity: Vec3::splat(100.0),
            }),
            PunctualLight::Directional(DirectionalLight {
                direction: Vec3::new(0.3, 0.2, -1.0).normalize(),
                illuminance: Vec3::new(0.5, 0.6, 0.7),
            }),
        ]
    }

    /// A Lambertian floor's f · cos (albedo 0.7, normal +z).
    fn lambert(ls: &PunctualSample) -> Vec3 {
        ls.li * (0.7 / std::f32::consts::PI) * ls.wi.z.max(0.0)
    }

    #[test]
    fn lamps_are_drawn_with_the_probability_they_report_in_proportion_to_what_they_send() {
        let lights = lamps();
        let p = Vec3::ZERO;
        let draws = 400_000;
        let mut seen = vec![0.0f64; lights.len()];
        let mut pmf = vec![0.0f32; lights.len()];
        let mut estimate = Vec3::ZERO.as_dvec3();
        for k in 0..draws {
            let u = (k as f32 + 0.5) / draws as f32;
            let c = choose_by_contribution(&lights, p, u, lambert).expect("lit");
            seen[c.index] += 1.0;
            pmf[c.index] = c.pmf;
            estimate += (c.contribution / c.pmf).as_dvec3();
        }
        let n = f64::from(draws);
        // Pearson χ² of the counts against the reported probabilities (the zero-probability lamps
        // must not be drawn at all).
        let mut chi2 = 0.0;
        let mut cells = 0;
        for (i, (&s, &q)) in seen.iter().zip(&pmf).enumerate() {
            if q == 0.0 {
                assert_eq!(s, 0.0, "lamp {i} has probability 0 but was drawn");
                continue;
            }
            let expected = n * f64::from(q);
            chi2 += (s - expected).powi(2) / expected;
            cells += 1;
        }
        // Stratified u: far below the 99.9 % point of χ² with ≤ 4 degrees of freedom (18.5).
        assert!(chi2 < 18.5, "χ² = {chi2} over {cells} lamps");
        // The spot pointing up and the lamp below the floor light nothing: never drawn.
        assert_eq!(seen[2], 0.0);
        assert_eq!(seen[3], 0.0);
        assert_eq!(cells, 3);
        // Each probability is the lamp's share of the point's unshadowed light, so the estimator
        // is the sum of every lamp's contribution.
        let exact: Vec3 = lights
            .iter()
            .filter_map(|l| l.sample_li(p))
            .map(|ls| lambert(&ls))
            .sum();
        let mean = estimate / n;
        assert!(
            (mean - exact.as_dvec3()).abs().max_element() < 1e-4 * exact.max_element() as f64,
            "{mean} against {exact}"
        );
        let total = luminance(exact);
        for (i, l) in lights.iter().enumerate() {
            let want = l
                .sample_li(p)
                .map_or(0.0, |ls| luminance(lambert(&ls)) / total);
            assert!(
                (pmf[i] - want).abs() < 1e-5,
                "lamp {i}: {} against {want}",
                pmf[i]
            );
        }
    }

    #[test]
    fn a_point_no_lamp_lights_has_no_lamp() {
        let lights = lamps();
        // The spot pointing up, and the lamp below the floor (behind the surface).
        for only in [2, 3] {
            let one = &lights[only..only + 1];
            assert!(choose_by_contribution(one, Vec3::ZERO, 0.5, lambert).is_none());
        }
        assert!(choose_by_contribution(&[], Vec3::ZERO, 0.5, lambert).is_none());
    }

    #[test]
    fn a_single_lamp_that_lights_the_point_is_certain() {
        let lights = &lamps()[..1];
        for u in [0.0, 0.3, 0.999_999] {
            let c = choose_by_contribution(lights, Vec3::ZERO, u, lambert).expect("lit");
            assert_eq!((c.index, c.pmf), (0, 1.0));
        }
    }
}
