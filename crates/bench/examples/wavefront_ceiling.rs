//! An upper-bound experiment, not the tracer: how many Cornell-box camera paths per second eight
//! paths in SIMD lanes can reach with the tracer's estimator (MIS of light-area and cosine BSDF
//! sampling, Russian roulette after the fourth vertex on the largest throughput component), so that
//! the wavefront integrator is known to be worth building, and where its time will go, before it is
//! built.
//!
//! `cargo run --release -p pathfarm-bench --example wavefront_ceiling -- [THREADS] [SPP]`
//! (with `RUSTFLAGS="-C target-cpu=native"` for 8-wide AVX2 lanes; the baseline build has 4-wide
//! SSE2). It renders the box, then renders it again with the tracer, and prints both throughputs and
//! both image means (which agree within 0.1 %: the same estimator, other random numbers).
//!
//! What it leaves out, each of which makes it faster than a faithful wavefront would be: the BVH
//! (every ray is tested against all 32 triangles, Möller–Trumbore instead of the watertight test),
//! the Owen-scrambled Sobol sampler (a hash per dimension instead), the robust ray-origin offset
//! (a fixed epsilon), fixed-point accumulation, and every material but the Lambertian.
//!
//! Measured (docs/benchmarks.md, "Later (November 24, night)"): 1.63× the tracer's samples per
//! second with AVX2 (3.50 against 2.15 M), 1.18× with SSE2. About 70 % of its time is the
//! ray/triangle tests (32 per ray, 8 rays at once: per ray, about what the tracer's BVH costs), so
//! vectorising the shading alone cannot reach the 6 M samples/s target: the intersection has to get
//! cheaper too.

use pathfarm_bench::render::render_range;
use pathfarm_bench::scenes;
use rayon::prelude::*;
use std::path::Path;
use std::time::Instant;

const L: usize = 8;
type F = [f32; L];
type U = [u32; L];

#[inline(always)]
fn f(g: impl Fn(usize) -> f32) -> F {
    std::array::from_fn(g)
}

#[derive(Clone, Copy)]
struct V {
    x: F,
    y: F,
    z: F,
}

impl V {
    #[inline(always)]
    fn splat(v: glam::Vec3) -> V {
        V {
            x: [v.x; L],
            y: [v.y; L],
            z: [v.z; L],
        }
    }
    #[inline(always)]
    fn dot(&self, o: &V) -> F {
        f(|i| self.x[i] * o.x[i] + self.y[i] * o.y[i] + self.z[i] * o.z[i])
    }
    #[inline(always)]
    fn cross(&self, o: &V) -> V {
        V {
            x: f(|i| self.y[i] * o.z[i] - self.z[i] * o.y[i]),
            y: f(|i| self.z[i] * o.x[i] - self.x[i] * o.z[i]),
            z: f(|i| self.x[i] * o.y[i] - self.y[i] * o.x[i]),
        }
    }
    #[inline(always)]
    fn sub(&self, o: &V) -> V {
        V {
            x: f(|i| self.x[i] - o.x[i]),
            y: f(|i| self.y[i] - o.y[i]),
            z: f(|i| self.z[i] - o.z[i]),
        }
    }
    #[inline(always)]
    fn madd(&self, t: &F, d: &V) -> V {
        V {
            x: f(|i| self.x[i] + t[i] * d.x[i]),
            y: f(|i| self.y[i] + t[i] * d.y[i]),
            z: f(|i| self.z[i] + t[i] * d.z[i]),
        }
    }
    #[inline(always)]
    fn scale(&self, s: &F) -> V {
        V {
            x: f(|i| self.x[i] * s[i]),
            y: f(|i| self.y[i] * s[i]),
            z: f(|i| self.z[i] * s[i]),
        }
    }
    #[inline(always)]
    fn mul(&self, o: &V) -> V {
        V {
            x: f(|i| self.x[i] * o.x[i]),
            y: f(|i| self.y[i] * o.y[i]),
            z: f(|i| self.z[i] * o.z[i]),
        }
    }
    #[inline(always)]
    fn add(&self, o: &V) -> V {
        V {
            x: f(|i| self.x[i] + o.x[i]),
            y: f(|i| self.y[i] + o.y[i]),
            z: f(|i| self.z[i] + o.z[i]),
        }
    }
    #[inline(always)]
    fn select(m: &[bool; L], a: &V, b: &V) -> V {
        V {
            x: f(|i| if m[i] { a.x[i] } else { b.x[i] }),
            y: f(|i| if m[i] { a.y[i] } else { b.y[i] }),
            z: f(|i| if m[i] { a.z[i] } else { b.z[i] }),
        }
    }
    fn set(&mut self, i: usize, v: glam::Vec3) {
        self.x[i] = v.x;
        self.y[i] = v.y;
        self.z[i] = v.z;
    }
    fn get(&self, i: usize) -> glam::Vec3 {
        glam::Vec3::new(self.x[i], self.y[i], self.z[i])
    }
}

/// The scene as flat arrays: triangles (corner, edges, unit normal), albedo and front-face emission.
struct Flat {
    v0: Vec<glam::Vec3>,
    e1: Vec<glam::Vec3>,
    e2: Vec<glam::Vec3>,
    n: Vec<glam::Vec3>,
    albedo: Vec<glam::Vec3>,
    emission: Vec<glam::Vec3>,
    /// Emissive triangles, chosen uniformly (the box's two light triangles are equal).
    lights: Vec<usize>,
    light_pdf_area: f32,
}

#[inline(always)]
fn hash(mut x: U) -> U {
    for v in x.iter_mut() {
        *v ^= *v >> 16;
        *v = v.wrapping_mul(0x21f0_aaad);
        *v ^= *v >> 15;
        *v = v.wrapping_mul(0x735a_2d97);
        *v ^= *v >> 15;
    }
    x
}

#[inline(always)]
fn rand(key: &U, dim: &U) -> F {
    let h = hash(std::array::from_fn(|i| {
        key[i] ^ dim[i].wrapping_mul(0x9e37_79b9)
    }));
    f(|i| (h[i] >> 8) as f32 * (1.0 / 16_777_216.0))
}

/// sin and cos of |x| ≤ π/4 (Taylor to x⁹ / x⁸: ample for a ceiling).
#[inline(always)]
fn sin_cos(x: F) -> (F, F) {
    let s = f(|i| {
        let x2 = x[i] * x[i];
        x[i] * (1.0
            + x2 * (-1.0 / 6.0 + x2 * (1.0 / 120.0 + x2 * (-1.0 / 5040.0 + x2 / 362_880.0))))
    });
    let c = f(|i| {
        let x2 = x[i] * x[i];
        1.0 + x2 * (-0.5 + x2 * (1.0 / 24.0 + x2 * (-1.0 / 720.0 + x2 / 40320.0)))
    });
    (s, c)
}

/// Cosine-weighted local direction from two uniforms (concentric disk, Shirley–Chiu).
#[inline(always)]
fn cosine_dir(u1: F, u2: F) -> (F, F, F) {
    let a = f(|i| 2.0 * u1[i] - 1.0);
    let b = f(|i| 2.0 * u2[i] - 1.0);
    let first = std::array::from_fn::<bool, L, _>(|i| a[i].abs() > b[i].abs());
    let r = f(|i| if first[i] { a[i] } else { b[i] });
    let theta = f(|i| {
        let q = std::f32::consts::FRAC_PI_4;
        if first[i] {
            q * (b[i] / a[i])
        } else if b[i] == 0.0 {
            0.0
        } else {
            q * (a[i] / b[i])
        }
    });
    let (s, c) = sin_cos(theta);
    // In the second case the angle is π/2 − θ: swap sine and cosine.
    let x = f(|i| r[i] * if first[i] { c[i] } else { s[i] });
    let y = f(|i| r[i] * if first[i] { s[i] } else { c[i] });
    let z = f(|i| (1.0 - x[i] * x[i] - y[i] * y[i]).max(0.0).sqrt());
    (x, y, z)
}

/// Lane masks: all ones (true) or zero, so that selects compile to blends.
type M = [u32; L];

#[inline(always)]
fn mask(g: impl Fn(usize) -> bool) -> M {
    std::array::from_fn(|i| if g(i) { u32::MAX } else { 0 })
}

#[inline(always)]
fn blend(m: &M, a: &F, b: &F) -> F {
    f(|i| f32::from_bits((a[i].to_bits() & m[i]) | (b[i].to_bits() & !m[i])))
}

/// Closest hit of eight rays against every triangle: distance (∞ for a miss) and triangle.
#[inline(always)]
fn closest(s: &Flat, o: &V, d: &V, active: &[bool; L]) -> (F, U) {
    let mut best = f(|i| if active[i] { f32::INFINITY } else { 0.0 });
    let mut id = [u32::MAX; L];
    for t in 0..s.v0.len() {
        let (hit, tt) = test(s, t, o, d, &best);
        best = blend(&hit, &tt, &best);
        id = std::array::from_fn(|i| (t as u32 & hit[i]) | (id[i] & !hit[i]));
    }
    (best, id)
}

/// Whether anything blocks each ray before `t_max`.
#[inline(always)]
fn occluded(s: &Flat, o: &V, d: &V, t_max: &F) -> [bool; L] {
    let mut blocked = [0u32; L];
    for t in 0..s.v0.len() {
        let (hit, _) = test(s, t, o, d, t_max);
        blocked = std::array::from_fn(|i| blocked[i] | hit[i]);
    }
    blocked.map(|b| b != 0)
}

#[inline(always)]
fn test(s: &Flat, t: usize, o: &V, d: &V, t_max: &F) -> (M, F) {
    let e1 = V::splat(s.e1[t]);
    let e2 = V::splat(s.e2[t]);
    let p = d.cross(&e2);
    let det = e1.dot(&p);
    let inv = f(|i| 1.0 / det[i]);
    let tv = o.sub(&V::splat(s.v0[t]));
    let (up, q) = (tv.dot(&p), tv.cross(&e1));
    let (vq, tq) = (d.dot(&q), e2.dot(&q));
    let u = f(|i| up[i] * inv[i]);
    let v = f(|i| vq[i] * inv[i]);
    let tt = f(|i| tq[i] * inv[i]);
    let m1 = mask(|i| u[i] >= 0.0);
    let m2 = mask(|i| v[i] >= 0.0);
    let m3 = mask(|i| u[i] + v[i] <= 1.0);
    let m4 = mask(|i| tt[i] > 0.0);
    let m5 = mask(|i| tt[i] < t_max[i]);
    (
        std::array::from_fn(|i| m1[i] & m2[i] & m3[i] & m4[i] & m5[i]),
        tt,
    )
}

struct Lanes {
    o: V,
    d: V,
    beta: V,
    l: V,
    bsdf_pdf: F,
    depth: U,
    key: U,
    pixel: U,
    active: [bool; L],
}

fn render_row(s: &Flat, scene: &pathfarm_tracer::Scene, y: u32, spp: u32, sums: &mut [[f64; 3]]) {
    let width = 256u32;
    let items = width * spp;
    let mut next = 0u32;
    let zero = V::splat(glam::Vec3::ZERO);
    let mut st = Lanes {
        o: zero,
        d: zero,
        beta: zero,
        l: zero,
        bsdf_pdf: [0.0; L],
        depth: [0; L],
        key: [0; L],
        pixel: [0; L],
        active: [false; L],
    };
    loop {
        // Refill finished lanes with the next camera samples.
        for i in 0..L {
            if st.active[i] {
                continue;
            }
            if next >= items {
                continue;
            }
            let (x, index) = (next / spp, next % spp);
            next += 1;
            let key = pathfarm_tracer::sampler::hash_words(&[1, y, x, index]);
            let jx = (key & 0xffff) as f32 / 65536.0;
            let jy = (key >> 16) as f32 / 65536.0;
            let ray = scene.camera.generate_ray(
                glam::Vec2::new(x as f32 + jx, y as f32 + jy),
                width,
                width,
            );
            st.o.set(i, ray.o);
            st.d.set(i, ray.d);
            st.beta.set(i, glam::Vec3::ONE);
            st.l.set(i, glam::Vec3::ZERO);
            st.depth[i] = 0;
            st.key[i] = pathfarm_tracer::sampler::hash_u32(key);
            st.pixel[i] = x;
            st.active[i] = true;
        }
        if !st.active.iter().any(|&a| a) {
            return;
        }
        let (t, id) = closest(s, &st.o, &st.d, &st.active);
        let mut n = zero;
        let mut alb = zero;
        let mut le = zero;
        let mut alive = st.active;
        for i in 0..L {
            if !st.active[i] {
                continue;
            }
            if id[i] == u32::MAX {
                alive[i] = false;
                continue;
            }
            let k = id[i] as usize;
            n.set(i, s.n[k]);
            alb.set(i, s.albedo[k]);
            le.set(i, s.emission[k]);
        }
        let p = st.o.madd(&t, &st.d);
        let cos_o = st.d.dot(&n);
        // Emission (front faces only), weighted against light sampling after the first vertex.
        let w_e = f(|i| {
            if !alive[i] || cos_o[i] >= 0.0 {
                return 0.0;
            }
            if st.depth[i] == 0 {
                return 1.0;
            }
            let lp = s.light_pdf_area * t[i] * t[i] / -cos_o[i];
            let (a, b) = (st.bsdf_pdf[i] * st.bsdf_pdf[i], lp * lp);
            a / (a + b)
        });
        st.l = st.l.add(&st.beta.mul(&le).scale(&w_e));
        // The shading normal faces the incoming ray.
        let flip = std::array::from_fn::<bool, L, _>(|i| cos_o[i] > 0.0);
        let nf = V::select(&flip, &n.scale(&[-1.0; L]), &n);
        let dim = st.depth.map(|d| d * 8);
        // Light sample.
        let u_sel = rand(&st.key, &dim);
        let u1 = rand(&st.key, &dim.map(|d| d + 1));
        let u2 = rand(&st.key, &dim.map(|d| d + 2));
        let su = u1.map(f32::sqrt);
        let mut lp = zero;
        let mut ln = zero;
        let mut lle = zero;
        for i in 0..L {
            let k = s.lights[((u_sel[i] * s.lights.len() as f32) as usize).min(s.lights.len() - 1)];
            let (b0, b1) = (1.0 - su[i], u2[i] * su[i]);
            lp.set(i, s.v0[k] + s.e1[k] * (1.0 - b0 - b1) + s.e2[k] * b1);
            ln.set(i, s.n[k]);
            lle.set(i, s.emission[k]);
        }
        let to = lp.sub(&p);
        let dist2 = to.dot(&to);
        let dist = dist2.map(f32::sqrt);
        let wi_l = to.scale(&f(|i| 1.0 / dist[i]));
        let cos_l = wi_l.dot(&ln).map(|c| -c);
        let cos_i = wi_l.dot(&nf);
        let light_pdf = f(|i| s.light_pdf_area * dist2[i] / cos_l[i]);
        let w_l = f(|i| {
            if !alive[i] || cos_l[i] <= 0.0 || cos_i[i] <= 0.0 {
                return 0.0;
            }
            let bp = cos_i[i] * std::f32::consts::FRAC_1_PI;
            let (a, b) = (light_pdf[i] * light_pdf[i], bp * bp);
            bp / (a + b) * light_pdf[i]
        });
        let eps = 1e-4;
        let shadow_o = p.add(&nf.scale(&[eps; L]));
        let t_max = f(|i| {
            if w_l[i] > 0.0 {
                dist[i] * (1.0 - 1e-4)
            } else {
                0.0
            }
        });
        // The direct contribution: beta · albedo/π · cos · Le · w / pdf (w_l holds cos/π · w / pdf).
        let direct = st.beta.mul(&alb).mul(&lle).scale(&w_l);
        // BSDF sample.
        let (lx, ly, lz) = cosine_dir(
            rand(&st.key, &dim.map(|d| d + 3)),
            rand(&st.key, &dim.map(|d| d + 4)),
        );
        let sign = f(|i| 1f32.copysign(nf.z[i]));
        let a = f(|i| -1.0 / (sign[i] + nf.z[i]));
        let b = f(|i| nf.x[i] * nf.y[i] * a[i]);
        let tx = V {
            x: f(|i| 1.0 + sign[i] * nf.x[i] * nf.x[i] * a[i]),
            y: f(|i| sign[i] * b[i]),
            z: f(|i| -sign[i] * nf.x[i]),
        };
        let ty = V {
            x: b,
            y: f(|i| sign[i] + nf.y[i] * nf.y[i] * a[i]),
            z: f(|i| -nf.y[i]),
        };
        let wi = tx.scale(&lx).add(&ty.scale(&ly)).add(&nf.scale(&lz));
        st.bsdf_pdf = f(|i| lz[i] * std::f32::consts::FRAC_1_PI);
        st.beta = st.beta.mul(&alb);
        // Russian roulette after the fourth vertex.
        let u_rr = rand(&st.key, &dim.map(|d| d + 5));
        for i in 0..L {
            let q = st.beta.x[i].max(st.beta.y[i]).max(st.beta.z[i]).min(1.0);
            if q <= 0.0 || lz[i] <= 0.0 {
                alive[i] = false;
            } else if st.depth[i] >= 3 && q < 1.0 {
                if u_rr[i] >= q {
                    alive[i] = false;
                } else {
                    st.beta.x[i] /= q;
                    st.beta.y[i] /= q;
                    st.beta.z[i] /= q;
                }
            }
        }
        let blocked = occluded(s, &shadow_o, &wi_l, &t_max);
        let unblocked = f(|i| {
            if blocked[i] || t_max[i] == 0.0 {
                0.0
            } else {
                1.0
            }
        });
        st.l = st.l.add(&direct.scale(&unblocked));
        st.o = p.add(&nf.scale(&[eps; L]));
        st.d = wi;
        for i in 0..L {
            st.depth[i] += 1;
            if st.active[i] && !alive[i] {
                let c = st.l.get(i);
                let px = &mut sums[st.pixel[i] as usize];
                px[0] += c.x as f64;
                px[1] += c.y as f64;
                px[2] += c.z as f64;
                st.active[i] = false;
            }
        }
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let threads: usize = args.first().map_or(Ok(2), |s| s.parse())?;
    let spp: u32 = args.get(1).map_or(Ok(64), |s| s.parse())?;
    let scene = scenes::load(&scenes::find("cornell")?, Path::new("scenes"))?.scene;
    let mut flat = Flat {
        v0: vec![],
        e1: vec![],
        e2: vec![],
        n: vec![],
        albedo: vec![],
        emission: vec![],
        lights: vec![],
        light_pdf_area: 0.0,
    };
    let mut light_area = 0.0;
    for (k, [a, b, c]) in scene.mesh.positions.iter().enumerate() {
        let m = &scene.materials[scene.mesh.material[k] as usize];
        flat.v0.push(*a);
        flat.e1.push(*b - *a);
        flat.e2.push(*c - *a);
        flat.n.push((*b - *a).cross(*c - *a).normalize());
        flat.albedo.push(m.base_color.truncate());
        flat.emission.push(m.emissive);
        if m.emissive != glam::Vec3::ZERO {
            flat.lights.push(k);
            light_area += 0.5 * (*b - *a).cross(*c - *a).length();
        }
    }
    flat.light_pdf_area = 1.0 / light_area;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let start = Instant::now();
    let rows: Vec<Vec<[f64; 3]>> = pool.install(|| {
        (0..256u32)
            .into_par_iter()
            .map(|y| {
                let mut sums = vec![[0.0f64; 3]; 256];
                render_row(&flat, &scene, y, spp, &mut sums);
                sums
            })
            .collect()
    });
    let seconds = start.elapsed().as_secs_f64();
    let mean: f64 = rows
        .iter()
        .flatten()
        .map(|p| p[0] + p[1] + p[2])
        .sum::<f64>()
        / (3.0 * 256.0 * 256.0 * spp as f64);
    let settings = pathfarm_bench::speed::settings(256, 256, 1);
    let r = pool.install(|| render_range(&scene, &settings, 0..spp));
    let img = r.acc.mean_image();
    let tracer_mean: f64 =
        img.iter().map(|p| (p[0] + p[1] + p[2]) as f64).sum::<f64>() / (3.0 * img.len() as f64);
    let samples = 256.0 * 256.0 * spp as f64;
    println!(
        "lanes {L}: {threads} threads, {spp} spp: {seconds:.3} s, {:.3} M samples/s, mean {mean:.5}; tracer {:.3} M samples/s, mean {tracer_mean:.5} ({:+.2} %)",
        samples / seconds / 1e6,
        samples / r.seconds / 1e6,
        (mean / tracer_mean - 1.0) * 100.0
    );
    Ok(())
}
