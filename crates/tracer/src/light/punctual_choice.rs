//! Choosing among many punctual lamps by a light tree: a lit street or city exported from Blender
//! brings hundreds of point and spot lamps, and chosen by power alone most shading points sample
//! a lamp far off or pointing elsewhere (docs/benchmarks.md, "Punctual lamps in a light tree").
//!
//! Point and spot lights go into a [`LightTree`] (a point has no extent and lights every
//! direction; a spot lights its cone, [`LightBounds::spot`]). Directional lights have no position
//! to bound, so they stay a family of their own chosen by power: a sample goes to them with the
//! probability of their share of the punctual power, and to the tree otherwise (the selection
//! number is remapped, so no dimension is added). Both are unbiased: every lamp that can light a
//! point has a non-zero probability there.

use super::tree::{LightBounds, LightTree, ONE_BELOW};
use super::PunctualLight;
use crate::sampling::Distribution1D;
use glam::Vec3;

/// The tree over a scene's point and spot lights, and the directional lights beside it.
#[derive(Clone, Debug)]
pub struct PunctualTree {
    /// The point and spot lights in the tree's light order, as indices into the scene's
    /// punctual lights.
    positional: Vec<u32>,
    tree: LightTree,
    /// The directional lights, as indices into the scene's punctual lights, and their choice by
    /// power.
    directional: Vec<u32>,
    directional_distribution: Distribution1D,
    /// The probability that a sample goes to a directional light (their share of the power; 0
    /// without any).
    directional_choice: f32,
    /// 1 − `directional_choice`, exactly 1 without directional lights.
    positional_choice: f32,
}

impl PunctualTree {
    /// The tree over `lights`, whose powers (as [`PunctualLight::power`] gives them) are
    /// `powers`. None when no point or spot light has power.
    pub fn new(lights: &[PunctualLight], powers: &[f32]) -> Option<PunctualTree> {
        let power = |i: usize| f64::from(powers[i].max(0.0)).min(f64::from(f32::MAX));
        let (mut positional, mut directional) = (Vec::new(), Vec::new());
        let (mut positional_power, mut directional_power) = (0.0f64, 0.0f64);
        for (i, light) in lights.iter().enumerate() {
            match light {
                PunctualLight::Directional(_) => {
                    directional.push(i as u32);
                    directional_power += power(i);
                }
                _ => {
                    positional.push(i as u32);
                    positional_power += power(i);
                }
            }
        }
        if !(positional_power > 0.0 && positional_power.is_finite()) {
            return None;
        }
        // What the tree weighs each lamp by: a point lamp's power, and for a spot that of a point
        // lamp of its intensity (4π I, as pbrt-v4's `SpotLight::Bounds`). The spot's cone bounds
        // already rule out the directions it does not light; its own power, smaller the narrower
        // its cone, would count the cone twice, and a narrow spot would seldom be chosen even
        // where it is the brightest lamp.
        let weight = |i: u32| match lights[i as usize] {
            PunctualLight::Spot(l) => {
                f64::from(4.0 * std::f32::consts::PI * crate::math::luminance(l.intensity))
                    .clamp(0.0, f64::from(f32::MAX))
            }
            _ => power(i as usize),
        };
        let total_weight: f64 = positional.iter().map(|&i| weight(i)).sum();
        if !(total_weight > 0.0 && total_weight.is_finite()) {
            return None;
        }
        let bounds: Vec<LightBounds> = positional
            .iter()
            .map(|&i| {
                let phi = (weight(i) / total_weight) as f32;
                match lights[i as usize] {
                    PunctualLight::Point(l) => LightBounds::point(l.position, phi),
                    PunctualLight::Spot(l) => {
                        LightBounds::spot(l.position, l.direction, l.cos_inner, l.cos_outer, phi)
                    }
                    PunctualLight::Directional(_) => unreachable!("only positional lights"),
                }
            })
            .collect();
        let directional_distribution = Distribution1D::new(
            &directional
                .iter()
                .map(|&i| powers[i as usize])
                .collect::<Vec<_>>(),
        );
        let (directional_choice, positional_choice) = if directional_distribution.is_empty() {
            (0.0, 1.0)
        } else {
            let p = (directional_power / (directional_power + positional_power)) as f32;
            (p, 1.0 - p)
        };
        Some(PunctualTree {
            positional,
            tree: LightTree::new(&bounds),
            directional,
            directional_distribution,
            directional_choice,
            positional_choice,
        })
    }

    /// Chooses a lamp for the point `p` with unit normal `n` (zero: none) from `u` in [0, 1):
    /// its index among the scene's punctual lights and its probability. None when no lamp can
    /// light `p`.
    #[inline]
    pub fn choose(&self, p: Vec3, n: Vec3, u: f32) -> Option<(usize, f32)> {
        let pd = self.directional_choice;
        if u < pd {
            let u = (u / pd).min(ONE_BELOW);
            let (k, pmf) = self.directional_distribution.sample_discrete(u);
            return Some((self.directional[k] as usize, pd * pmf));
        }
        let u = ((u - pd) / self.positional_choice).min(ONE_BELOW);
        let (k, pmf) = self.tree.sample(p, n, u)?;
        Some((self.positional[k] as usize, self.positional_choice * pmf))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::light::{DirectionalLight, PointLight, SpotLight};

    fn lamps() -> Vec<PunctualLight> {
        let mut lights = Vec::new();
        for k in 0..40 {
            let position = Vec3::new((k % 8) as f32 * 2.0, (k / 8) as f32 * 2.0, 3.0);
            lights.push(if k % 3 == 0 {
                PunctualLight::Spot(SpotLight {
                    position,
                    // Every sixth spot points up, away from the ground below.
                    direction: if k % 6 == 0 { Vec3::Z } else { -Vec3::Z },
                    intensity: Vec3::splat(5.0),
                    cos_inner: 0.9,
                    cos_outer: 0.7,
                })
            } else {
                PunctualLight::Point(PointLight {
                    position,
                    intensity: Vec3::splat(1.0 + k as f32 * 0.1),
                })
            });
        }
        lights.push(PunctualLight::Directional(DirectionalLight {
            direction: Vec3::new(0.3, 0.1, -1.0).normalize(),
            illuminance: Vec3::splat(2.0),
        }));
        lights
    }

    /// Every lamp's probability at `p`, from many uniform selection numbers.
    fn frequencies(tree: &PunctualTree, count: usize, p: Vec3, n: Vec3) -> (Vec<f64>, Vec<f32>) {
        let draws = 200_000;
        let (mut seen, mut pmf) = (vec![0.0; count], vec![0.0f32; count]);
        for k in 0..draws {
            let u = (k as f32 + 0.5) / draws as f32;
            if let Some((i, p_i)) = tree.choose(p, n, u) {
                seen[i] += 1.0 / draws as f64;
                pmf[i] = p_i;
            }
        }
        (seen, pmf)
    }

    #[test]
    fn lamps_are_chosen_with_the_probability_they_report() {
        let lights = lamps();
        let powers: Vec<f32> = lights.iter().map(|l| l.power(20.0)).collect();
        let tree = PunctualTree::new(&lights, &powers).expect("a tree");
        let (p, n) = (Vec3::new(3.0, 4.0, 0.0), Vec3::Z);
        let (seen, pmf) = frequencies(&tree, lights.len(), p, n);
        let total: f64 = pmf.iter().map(|&x| f64::from(x)).sum();
        assert!(total <= 1.0 + 1e-5 && total > 0.5, "{total}");
        for (i, (&f, &q)) in seen.iter().zip(&pmf).enumerate() {
            assert!(
                (f - f64::from(q)).abs() < 2e-5 + 0.01 * f64::from(q),
                "lamp {i}: drawn {f}, reported {q}"
            );
        }
        // A spot pointing up lights nothing below it: never chosen for the ground.
        for (i, light) in lights.iter().enumerate() {
            if let PunctualLight::Spot(s) = light {
                if s.direction == Vec3::Z {
                    assert_eq!(seen[i], 0.0, "spot {i} points away");
                }
            }
        }
        // The directional light keeps its share of the power.
        let sun = lights.len() - 1;
        let share = powers[sun] / powers.iter().sum::<f32>();
        assert!(
            (pmf[sun] - share).abs() < 1e-5,
            "{} against {share}",
            pmf[sun]
        );
        // Lamps near the point get more samples than the same lamps far off.
        let near = lights
            .iter()
            .position(|l| matches!(l, PunctualLight::Point(pl) if pl.position.truncate() == glam::Vec2::new(2.0, 4.0)))
            .unwrap();
        let far = lights
            .iter()
            .position(|l| matches!(l, PunctualLight::Point(pl) if pl.position.truncate() == glam::Vec2::new(14.0, 6.0)))
            .unwrap();
        assert!(
            pmf[near] > 5.0 * pmf[far],
            "{} against {}",
            pmf[near],
            pmf[far]
        );
    }

    /// A narrow spot aimed at a point is chosen there about as often as a point lamp of the same
    /// intensity at the same distance (both send I/d² there); weighed by its power it was chosen
    /// (1 − cos)/2 as often, a few in a thousand for this one.
    #[test]
    fn a_narrow_spot_weighs_as_a_lamp_of_its_intensity_where_it_shines() {
        let spot = PunctualLight::Spot(SpotLight {
            position: Vec3::new(0.0, 0.0, 3.0),
            direction: -Vec3::Z,
            intensity: Vec3::splat(2.0),
            cos_inner: 0.995,
            cos_outer: 0.99,
        });
        let lamp = PunctualLight::Point(PointLight {
            position: Vec3::new(0.0, 3.0, 0.0),
            intensity: Vec3::splat(2.0),
        });
        let lights = [spot, lamp];
        let powers: Vec<f32> = lights.iter().map(|l| l.power(20.0)).collect();
        let tree = PunctualTree::new(&lights, &powers).expect("a tree");
        // Lit head-on by the spot and from the side by the lamp: the normal halfway.
        let n = Vec3::new(0.0, 1.0, 1.0).normalize();
        let (_, pmf) = frequencies(&tree, 2, Vec3::ZERO, n);
        let ratio = pmf[0] / pmf[1];
        assert!(
            (0.5..=2.0).contains(&ratio),
            "spot {} against lamp {}",
            pmf[0],
            pmf[1]
        );
        // Beside its cone the spot lights nothing and is never chosen.
        let (seen, _) = frequencies(&tree, 2, Vec3::new(3.0, 0.0, 0.0), Vec3::Z);
        assert_eq!(seen[0], 0.0);
    }

    #[test]
    fn without_positional_power_there_is_no_tree() {
        let sun = PunctualLight::Directional(DirectionalLight {
            direction: -Vec3::Z,
            illuminance: Vec3::ONE,
        });
        assert!(PunctualTree::new(&[sun], &[1.0]).is_none());
    }
}
