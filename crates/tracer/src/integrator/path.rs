use super::direct::{direct_by_direction, direct_punctual, light_query, ShadowQuery, Vertex};
use super::EmissionWeight;
use crate::geometry::Ray;
use crate::math::{is_black, offset_ray_origin};
use crate::sampler::{dims, PixelSampler};
use crate::sampling::power_heuristic;
use crate::scene::{Hit, Scene};
use crate::settings::{DirectStrategy, RenderSettings, RussianRoulette};
use glam::Vec3;

/// The outcome of one camera path.
#[derive(Clone, Copy, Debug, Default)]
pub struct PathResult {
    /// Radiance carried to the camera (may be invalid: NaN or infinite values are caught by the
    /// caller).
    pub radiance: Vec3,
    /// Rays traced (closest-hit and shadow).
    pub rays: u32,
    /// Path vertices (surface hits).
    pub vertices: u32,
}

/// Traces one camera path starting with `ray`, drawing every random decision from `sampler`.
pub fn trace_path(
    scene: &Scene,
    settings: &RenderSettings,
    sampler: &PixelSampler,
    camera_ray: Ray,
) -> PathResult {
    let mut out = PathResult::default();
    let mut l = Vec3::ZERO;
    let mut beta = Vec3::ONE;
    let mut ray = camera_ray;
    let mut emission = EmissionWeight::Full;
    // Absorption coefficient of the volume the path is inside, if any.
    let mut medium: Option<Vec3> = None;
    let depth_limit = settings.depth_limit();
    let strategy = settings.direct;
    // Area lights or an environment: what the shared light sample finds.
    let has_sampled = scene.lights.has_sampled();
    let has_punctual = !scene.lights.punctual.is_empty();
    let caustics = scene.caustic_guide();

    let mut depth = 0u32;
    // The current ray's hit when it was traced together with the previous vertex's shadow ray.
    let mut traced: Option<Option<Hit>> = None;
    loop {
        let found = match traced.take() {
            Some(found) => found,
            None => {
                out.rays += 1;
                scene.intersect(&ray, f32::INFINITY, alpha_at(scene, sampler, depth))
            }
        };
        let Some(hit) = found else {
            // The ray left the scene: the environment's light along it, counted as emission is.
            if let Some(env) = &scene.lights.environment {
                let w = match emission {
                    EmissionWeight::Full => 1.0,
                    EmissionWeight::Skip { environment } => {
                        if environment {
                            0.0
                        } else {
                            1.0
                        }
                    }
                    EmissionWeight::Mis { bsdf_pdf, .. } => {
                        power_heuristic(bsdf_pdf, scene.lights.environment_choice * env.pdf(ray.d))
                    }
                };
                if w > 0.0 {
                    l += beta * env.radiance(ray.d) * w;
                }
            }
            break;
        };
        out.vertices += 1;
        let si = scene.surface(&ray, &hit);
        if let Some(sigma) = medium {
            beta *= (-sigma * hit.t).map(crate::math::det::exp);
        }
        let material = &scene.materials[si.material as usize];

        // 1. Emission seen by this ray.
        if material.is_emissive() {
            let le = material.emission(&scene.textures, &si.uv, si.front);
            if !is_black(le) {
                let w = match emission {
                    EmissionWeight::Full => 1.0,
                    EmissionWeight::Skip { .. } => 0.0,
                    EmissionWeight::Mis { bsdf_pdf, from, n } => {
                        let cos_l = ray.d.dot(si.ng).abs();
                        // Emitters are never instanced (`Scene::build` refuses them).
                        debug_assert_eq!(hit.instance, Hit::WORLD);
                        let light_pdf =
                            scene
                                .lights
                                .area
                                .pdf(from, n, hit.triangle, si.material, hit.t, cos_l)
                                * scene.lights.area_choice
                                * hit.t
                                * hit.t
                                / cos_l;
                        power_heuristic(bsdf_pdf, light_pdf)
                    }
                };
                l += beta * le * w;
            }
        }
        if depth >= depth_limit {
            break;
        }

        let bsdf = scene.bsdf_at(&si);
        let wo = -ray.d;
        // Where the caustic guide knows this point, the continuation is drawn from its mixture
        // with the BSDF (`guide`).
        let guide = match bsdf.has_non_delta() {
            true => caustics.and_then(|g| g.cell(si.p)),
            false => None,
        };
        let vertex = Vertex {
            p: si.p,
            clearance: si.clearance,
            ng: si.ng,
            wo,
            bsdf: &bsdf,
            medium,
            guide,
        };

        // 2. Direct lighting for the non-delta lobes. The area light's shadow ray is traced later,
        // together with the continuation ray (or alone if the path ends here); its contribution
        // is added before anything else is, so the sum's order, and its bits, are unchanged.
        let mut shadow: Option<ShadowQuery> = None;
        if bsdf.has_non_delta() {
            if has_punctual {
                l += beta * direct_punctual(scene, &vertex, sampler, depth, &mut out.rays);
            }
            match strategy {
                DirectStrategy::Light | DirectStrategy::Mis if has_sampled => {
                    let mis = strategy == DirectStrategy::Mis;
                    shadow = light_query(scene, &vertex, sampler, depth, mis).map(|q| {
                        out.rays += 1;
                        ShadowQuery {
                            value: beta * q.value,
                            ..q
                        }
                    });
                }
                DirectStrategy::Hemisphere | DirectStrategy::Cosine if has_sampled => {
                    l += beta
                        * direct_by_direction(
                            scene,
                            &vertex,
                            sampler,
                            depth,
                            strategy,
                            &mut out.rays,
                        );
                }
                _ => {}
            }
        }

        // 3. Continue the path.
        let u_dir = sampler.bounce2(depth, dims::BSDF_DIR);
        let sampled = match &guide {
            // The lobe's dimension chooses between the guide and the BSDF, and then within it.
            Some(cell) => {
                let u_mix = sampler.bounce1(depth, dims::BSDF_LOBE);
                cell.sample_mixture(&bsdf, wo, si.ng, u_mix, u_dir)
            }
            // A pure Lambertian has one lobe: its dimension is not drawn at all.
            None if bsdf.single_lobe() => bsdf.sample(wo, 0.0, u_dir),
            None => bsdf.sample(wo, sampler.bounce1(depth, dims::BSDF_LOBE), u_dir),
        };
        let Some(bs) = sampled.filter(|bs| !is_black(bs.weight)) else {
            l += shadow_alone(scene, shadow);
            break;
        };
        beta *= bs.weight;
        if is_black(beta) {
            // The throughput underflowed (a long path without roulette, or full absorption):
            // nothing further can contribute, and without this test the path would run on to
            // the safety cap of 65,536 bounces.
            l += shadow_alone(scene, shadow);
            break;
        }
        emission = if bs.delta {
            EmissionWeight::Full
        } else {
            match strategy {
                DirectStrategy::Bsdf => EmissionWeight::Full,
                DirectStrategy::Mis => EmissionWeight::Mis {
                    bsdf_pdf: bs.pdf,
                    from: si.p,
                    n: si.ng,
                },
                DirectStrategy::Light | DirectStrategy::Hemisphere | DirectStrategy::Cosine => {
                    if has_sampled {
                        // A direction sample finds the environment; a light sample only where it
                        // may choose it.
                        let environment = strategy != DirectStrategy::Light
                            || scene.lights.sampled_environment().is_some();
                        EmissionWeight::Skip { environment }
                    } else {
                        EmissionWeight::Full
                    }
                }
            }
        };
        if bs.transmitted && scene.any_volume {
            // Crossing the boundary of a volume: entering from the front side, leaving from the back.
            if let Some(v) = material.volume.filter(|_| !bsdf.params().thin_walled) {
                medium = if wo.dot(si.ng) > 0.0 {
                    Some(v.sigma_a)
                } else {
                    None
                };
            }
        }

        // 4. Russian roulette.
        let survive = survival(settings.rr, depth, beta);
        if survive < 1.0 {
            if sampler.bounce1(depth, dims::ROULETTE) >= survive {
                l += shadow_alone(scene, shadow);
                break;
            }
            beta /= survive;
        }

        let side = if bs.wi.dot(si.ng) > 0.0 {
            si.ng
        } else {
            -si.ng
        };
        ray = Ray::new(offset_ray_origin(si.p, side, si.clearance), bs.wi);
        depth += 1;
        if let Some(q) = shadow {
            out.rays += 1;
            let alpha_u = alpha_at(scene, sampler, depth);
            let (found, visible) =
                scene.intersect_and_visible(&ray, alpha_u, &q.ray, q.t_max, q.alpha_u);
            if visible {
                l += q.value;
            }
            traced = Some(found);
        }
    }
    out.radiance = l;
    out
}

/// The probability that Russian roulette lets a path go on after vertex `depth`, whose throughput
/// is now `beta` (1: no roulette here).
#[inline(always)]
pub(crate) fn survival(rr: RussianRoulette, depth: u32, beta: Vec3) -> f32 {
    match rr {
        RussianRoulette::Off => 1.0,
        RussianRoulette::Auto => threshold_survival(0.5, 0.1, depth, beta),
        RussianRoulette::Max if depth >= 3 => beta.max_element().min(1.0),
        RussianRoulette::Max => 1.0,
        RussianRoulette::Fixed(p) if depth >= 1 => p,
        RussianRoulette::Fixed(_) => 1.0,
        RussianRoulette::Threshold { terminate, below } => {
            threshold_survival(terminate, below, depth, beta)
        }
    }
}

/// [`RussianRoulette::Threshold`]'s survival probability. (A function of its own rather than
/// `Auto` calling [`survival`] again: the recursion kept `survival` from being inlined, a call per
/// lane and bounce.)
#[inline(always)]
fn threshold_survival(terminate: f32, below: f32, depth: u32, beta: Vec3) -> f32 {
    if depth >= 1 && crate::math::luminance(beta) < below {
        1.0 - terminate
    } else {
        1.0
    }
}

/// The alpha-coverage sample of the closest-hit ray of bounce `depth` (none without alpha).
#[inline(always)]
fn alpha_at(scene: &Scene, sampler: &PixelSampler, depth: u32) -> f32 {
    if scene.any_alpha() {
        sampler.bounce1(depth, dims::ALPHA)
    } else {
        0.0
    }
}

/// The contribution of a pending shadow ray traced alone (the path ends at its vertex).
#[inline(always)]
fn shadow_alone(scene: &Scene, shadow: Option<ShadowQuery>) -> Vec3 {
    match shadow {
        Some(q) if scene.visible(&q.ray, q.t_max, q.alpha_u) => q.value,
        _ => Vec3::ZERO,
    }
}
