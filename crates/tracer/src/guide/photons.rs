//! The guide's photons: shot from the emissive triangles (by power) towards the caustic casters,
//! followed through their specular bounces, and binned by cell and direction where they first
//! meet a surface with a non-delta lobe after at least one specular bounce. Each photon carries its share of the lights' power (the aiming's density
//! divided out), so a cell's bins weigh directions as the caustic irradiance they bring.

use super::casters::{casters, Caster};
use super::{bin_of, CausticGuide, Occupancy, BINS, MIN_PHOTONS};
use crate::geometry::Ray;
use crate::math::{luminance, offset_ray_origin, spawn_clearance, Frame};
use crate::sampler::{hash_words, independent_sample};
use crate::sampling::{sample_uniform_sphere, sample_uniform_triangle};
use crate::scene::Scene;
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Photons per scene (2¹⁹ left the peers' caustics scene 1.2× noisier than 2²⁰).
const PHOTONS: u32 = 1 << 20;
/// Photons per chunk (a thread takes a run of chunks; their landings are collected in order).
const CHUNK: u32 = 1 << 14;
/// Specular bounces a photon follows before it is given up.
const MAX_SPECULAR: u32 = 12;
/// Grid cells along the longest axis of the scene's bounds: coarse, so that a caustic spread thin
/// (a convex mirror's) still leaves enough photons in a cell to name its directions (on the
/// peers' caustics scene 32 measured less noise than 16, 64 or 256).
const GRID_CELLS: f32 = 32.0;

/// Where a photon landed: cell key, direction bin, power.
type Landing = (u64, u16, f32);

/// The guide of `scene` (see [`CausticGuide::build`]).
pub(super) fn trace(scene: &Scene) -> Option<CausticGuide> {
    // Only emissive triangles: a path meets them, but never a lamp (a point or a direction), so
    // a lamp's caustics are beyond every path's reach and guiding towards them wastes samples.
    let area = &scene.lights.area;
    if area.is_empty() || area.total_power().is_nan() || area.total_power() <= 0.0 {
        return None;
    }
    let casters = casters(scene);
    if casters.is_empty() {
        return None;
    }
    let mut guide = empty_grid(scene);
    let shoot = Shoot {
        scene,
        casters: &casters,
        key: hash_words(&[0x6361_7573, 0x7469_6373]),
    };
    // Plain threads, one run of chunks each, not rayon: the guide is built inside a `OnceLock`'s
    // initialiser, often on a rayon thread of the render pool, and a rayon thread waiting for
    // its photon jobs would steal work from its pool, such as another task's tile, which would
    // then wait on the same `OnceLock` on the same thread: a deadlock. Chunks joined in order.
    let guide_ref = &guide;
    let shoot = &shoot;
    let threads = rayon::current_num_threads().clamp(1, 64) as u32;
    let chunks = PHOTONS / CHUNK;
    let per_thread = chunks.div_ceil(threads);
    let chunks: Vec<Vec<Landing>> = std::thread::scope(|scope| {
        let runs: Vec<_> = (0..threads)
            .map(|t| {
                scope.spawn(move || {
                    let mut out = Vec::new();
                    let first = (t * per_thread).min(chunks) * CHUNK;
                    let end = ((t + 1) * per_thread).min(chunks) * CHUNK;
                    for i in first..end {
                        shoot.photon(i, guide_ref, &mut out);
                    }
                    out
                })
            })
            .collect();
        runs.into_iter()
            .map(|run| run.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
            .collect()
    });
    let mut landings: Vec<Landing> = chunks.into_iter().flatten().collect();
    // A stable sort: equal (cell, bin) keep the photons' order, so every sum below is made in
    // the same order on every machine.
    landings.sort_by_key(|&(key, bin, _)| (key, bin));
    guide.photons = PHOTONS;
    guide.landed = landings.len() as u32;
    fill(&mut guide, &landings);
    (!guide.keys.is_empty()).then_some(guide)
}

/// The guide's grid over the scene's bounds (cubic cells), without cells yet.
fn empty_grid(scene: &Scene) -> CausticGuide {
    let (lo, hi) = (scene.info.bounds_min, scene.info.bounds_max);
    let extent = (hi - lo).max_element().max(1e-6);
    let cell = extent / GRID_CELLS;
    // A cell of margin on every side: points on the bounds' faces round either way.
    let lo = lo - Vec3::splat(cell);
    let size = (hi - lo) / cell + Vec3::splat(2.0);
    CausticGuide {
        lo,
        inv_cell: 1.0 / cell,
        dims: [size.x as u32, size.y as u32, size.z as u32],
        keys: Vec::new(),
        index: Vec::new(),
        ranges: Vec::new(),
        occupancy: Vec::new(),
        bins: Vec::new(),
        photons: 0,
        landed: 0,
    }
}

/// The cells of `guide` from the landings, sorted by (cell, bin): each cell with at least
/// [`MIN_PHOTONS`] photons, its bins' cumulative distribution.
fn fill(guide: &mut CausticGuide, landings: &[Landing]) {
    let mut start = 0;
    while start < landings.len() {
        let key = landings[start].0;
        let end = start + landings[start..].partition_point(|l| l.0 == key);
        let cell = &landings[start..end];
        start = end;
        if (cell.len() as u32) < MIN_PHOTONS {
            continue;
        }
        let mut per_bin: Vec<(u16, f64)> = Vec::new();
        for &(_, bin, w) in cell {
            match per_bin.last_mut() {
                Some((b, sum)) if *b == bin => *sum += f64::from(w),
                _ => per_bin.push((bin, f64::from(w))),
            }
        }
        let total: f64 = per_bin.iter().map(|(_, w)| w).sum();
        if !(total > 0.0 && total.is_finite()) {
            continue;
        }
        let first = guide.bins.len() as u32;
        let mut running = 0.0;
        for (bin, w) in per_bin {
            running += w;
            guide.bins.push((bin, (running / total) as f32));
        }
        if let Some(last) = guide.bins.last_mut() {
            last.1 = 1.0;
        }
        guide.keys.push(key);
        guide.ranges.push((first, guide.bins.len() as u32));
        guide
            .occupancy
            .push(Occupancy::of(&guide.bins[first as usize..]));
    }
    debug_assert!(guide.bins.iter().all(|&(b, _)| usize::from(b) < BINS));
    let [nx, ny, nz] = guide.dims;
    guide.index = vec![u32::MAX; nx as usize * ny as usize * nz as usize];
    for (i, &key) in guide.keys.iter().enumerate() {
        guide.index[key as usize] = i as u32;
    }
}

/// What shooting a photon needs.
struct Shoot<'a> {
    scene: &'a Scene,
    casters: &'a [Caster],
    key: u32,
}

impl Shoot<'_> {
    /// Photon `i`: emitted, aimed at a caster, and followed; where it lands is pushed to `out`.
    fn photon(&self, i: u32, grid: &CausticGuide, out: &mut Vec<Landing>) {
        let u = |dim: u32| independent_sample(self.key, i, dim);
        let n_casters = self.casters.len();
        let caster = self.casters[((u(1) * n_casters as f32) as usize).min(n_casters - 1)];
        let Some((ray, share)) = self.area_photon(caster, [u(2), u(3), u(4), u(5), u(6), u(7)])
        else {
            return;
        };
        // In units of the lights' power, for the caster chosen with probability 1 / n.
        let power = share * n_casters as f32;
        if !(power > 0.0 && power.is_finite()) {
            return;
        }
        self.follow(ray, power, |d| u(8 + d), grid, out);
    }

    /// A photon from the emissive triangles towards `caster`, and its share of their power
    /// (before the caster's choice).
    fn area_photon(&self, caster: Caster, u: [f32; 6]) -> Option<(Ray, f32)> {
        let area = &self.scene.lights.area;
        let (index, _) = area.distribution().sample_discrete(u[0]);
        let (light, triangle) = area.sampled_light(index)?;
        let b = sample_uniform_triangle(Vec2::new(u[1], u[2]));
        let p = light.corners[0] * b.x + light.corners[1] * b.y + light.corners[2] * b.z;
        let material = &self.scene.materials[self.scene.mesh.material[triangle as usize] as usize];
        // A two-sided emitter's sides, each half the time (its power counts both).
        let n = match material.double_sided && u[3] < 0.5 {
            true => -light.normal,
            false => light.normal,
        };
        let (w, solid_angle) = toward(p, caster, Vec2::new(u[4], u[5]));
        let cos = n.dot(w);
        if cos <= 0.0 {
            return None;
        }
        let o = offset_ray_origin(p, n, spawn_clearance(light.corners));
        // The area lights' share of their power per photon: triangle and side chosen by power,
        // the point by area, the direction in Ω: cos θ · Ω / π.
        Some((Ray::new(o, w), cos * solid_angle / PI))
    }

    /// Follows a photon through its specular bounces and records where it lands.
    fn follow(
        &self,
        mut ray: Ray,
        power: f32,
        u: impl Fn(u32) -> f32,
        grid: &CausticGuide,
        out: &mut Vec<Landing>,
    ) {
        let scene = self.scene;
        let mut beta = Vec3::ONE;
        for bounce in 0..=MAX_SPECULAR {
            let dim = 4 * bounce;
            let Some(hit) = scene.intersect(&ray, f32::INFINITY, u(dim)) else {
                return;
            };
            let si = scene.surface(&ray, &hit);
            let bsdf = scene.bsdf_at(&si);
            if bsdf.has_non_delta() {
                if bounce > 0 {
                    let w = power * luminance(beta);
                    if let Some(key) = grid.key(si.p).filter(|_| w > 0.0 && w.is_finite()) {
                        out.push((key, bin_of(-ray.d) as u16, w));
                    }
                }
                return;
            }
            let Some(bs) = bsdf.sample(-ray.d, u(dim + 1), Vec2::new(u(dim + 2), u(dim + 3)))
            else {
                return;
            };
            beta *= bs.weight;
            if crate::math::is_black(beta) {
                return;
            }
            let side = if bs.wi.dot(si.ng) > 0.0 {
                si.ng
            } else {
                -si.ng
            };
            ray = Ray::new(offset_ray_origin(si.p, side, si.clearance), bs.wi);
        }
    }
}

/// A direction from `p` uniform in the cone that `caster`'s bounding sphere subtends (the whole
/// sphere of directions from inside it), and that cone's solid angle.
fn toward(p: Vec3, caster: Caster, u: Vec2) -> (Vec3, f32) {
    let to = caster.center - p;
    let d2 = to.length_squared();
    let r2 = caster.radius * caster.radius;
    if d2 <= r2 {
        return (sample_uniform_sphere(u), 4.0 * PI);
    }
    let cos_max = (1.0 - r2 / d2).max(0.0).sqrt();
    let cos = 1.0 - u.x * (1.0 - cos_max);
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    let (sin_phi, cos_phi) = crate::math::det::sin_cos_turns(u.y);
    let local = Vec3::new(sin * cos_phi, sin * sin_phi, cos);
    let w = Frame::from_z(to / d2.sqrt()).to_world(local);
    (w, 2.0 * PI * (1.0 - cos_max))
}
