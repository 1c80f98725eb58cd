//! Direct-lighting estimators at one path vertex. Each returns the contribution *before* the path
//! throughput is applied.

use crate::bsdf::Bsdf;
use crate::geometry::Ray;
use crate::guide::GuideCell;
use crate::light::{choose_by_contribution, PunctualSample};
use crate::math::{is_black, offset_ray_origin, Frame};
use crate::sampler::{dims, PixelSampler};
use crate::sampling::{
    cosine_hemisphere_pdf, power_heuristic, sample_cosine_hemisphere, sample_uniform_hemisphere,
    uniform_hemisphere_pdf,
};
use crate::scene::Scene;
use crate::settings::DirectStrategy;
use glam::{Vec2, Vec3};

/// The path vertex being lit.
pub(crate) struct Vertex<'a> {
    pub p: Vec3,
    /// How far from the surface rays spawned here start ([`crate::math::spawn_clearance`]).
    pub clearance: f32,
    /// Unit geometric normal (front side).
    pub ng: Vec3,
    pub wo: Vec3,
    pub bsdf: &'a Bsdf,
    /// Absorption of the medium the vertex is in (shadow rays through it are attenuated).
    pub medium: Option<Vec3>,
    /// The caustic guide's cell, where the continuation is drawn from its mixture with the BSDF:
    /// the BSDF strategy's density in the MIS weights is then the mixture's.
    pub guide: Option<GuideCell<'a>>,
}

impl Vertex<'_> {
    /// The BSDF's f · |cos θi| towards `wi`, and the density with which the continuation is drawn
    /// there (the BSDF's, or its mixture with the caustic guide).
    #[inline]
    fn eval_pdf(&self, wi: Vec3) -> (Vec3, f32) {
        let (f, pdf) = self.bsdf.eval_pdf(self.wo, wi);
        match &self.guide {
            Some(cell) => (f, cell.mix_pdf(pdf, wi)),
            None => (f, pdf),
        }
    }

    /// A ray leaving the vertex towards `wi`, its origin offset to the side `wi` goes to.
    #[inline]
    fn spawn(&self, wi: Vec3) -> Ray {
        spawn(self.p, self.ng, self.clearance, wi)
    }

    #[inline]
    fn transmittance(&self, dist: f32) -> Vec3 {
        match self.medium {
            Some(sigma) if dist.is_finite() => (-sigma * dist).map(crate::math::det::exp),
            _ => Vec3::ONE,
        }
    }
}

/// A ray leaving `p` (geometric normal `ng`) towards `wi`, its origin offset to the side `wi` goes
/// to.
#[inline]
fn spawn(p: Vec3, ng: Vec3, clearance: f32, wi: Vec3) -> Ray {
    let side = if wi.dot(ng) > 0.0 { ng } else { -ng };
    Ray::new(offset_ray_origin(p, side, clearance), wi)
}

/// Shadow rays stop this fraction short of the light so they do not hit the light's own triangle.
pub(crate) const SHADOW_EPSILON: f32 = 1e-4;

/// One punctual light, chosen in proportion to power (by a light tree when there are many).
/// Delta lights can only be reached this way, so every strategy calls it.
pub(crate) fn direct_punctual(
    scene: &Scene,
    v: &Vertex,
    s: &PixelSampler,
    depth: u32,
    rays: &mut u32,
) -> Vec3 {
    let at = PunctualAt {
        p: v.p,
        ng: v.ng,
        clearance: v.clearance,
        u_select: s.bounce1(depth, dims::PUNCTUAL_SELECT),
        alpha_u: if scene.any_alpha() {
            s.bounce1(depth, dims::ALPHA)
        } else {
            0.0
        },
    };
    punctual_at::<false>(
        scene,
        &at,
        rays,
        |wi| v.bsdf.eval(v.wo, wi),
        |dist| v.transmittance(dist),
    )
}

/// Where [`punctual_at`] lights, and its sample values.
pub(crate) struct PunctualAt {
    pub p: Vec3,
    pub ng: Vec3,
    pub clearance: f32,
    /// Chooses the light (`dims::PUNCTUAL_SELECT`).
    pub u_select: f32,
    /// The shadow ray's alpha-coverage value (`dims::ALPHA`).
    pub alpha_u: f32,
}

/// [`direct_punctual`]'s body, with the BSDF's f · |cos θi| towards `wi` as `eval` and the
/// medium's transmittance over a distance as `transmittance`: the scalar integrator and the
/// wavefront lanes (which keep no `Bsdf`) share it, so their bits are the same. `INLINED`: the
/// shadow ray's query inlined, as in `Scene::visible_in`.
#[inline(always)]
pub(crate) fn punctual_at<const INLINED: bool>(
    scene: &Scene,
    at: &PunctualAt,
    rays: &mut u32,
    eval: impl Fn(Vec3) -> Vec3,
    transmittance: impl Fn(f32) -> Vec3,
) -> Vec3 {
    let Some(q) = punctual_query(scene, at, eval, transmittance) else {
        return Vec3::ZERO;
    };
    *rays += 1;
    if !scene.visible_in::<INLINED>(&q.ray, q.t_max, q.alpha_u) {
        return Vec3::ZERO;
    }
    q.value
}

/// [`punctual_at`]'s lamp sample, up to its shadow ray: the ray and what it adds if the lamp is
/// visible, or None where no lamp lights the point (the lanes trace the rays two at a time).
#[inline(always)]
pub(crate) fn punctual_query(
    scene: &Scene,
    at: &PunctualAt,
    eval: impl Fn(Vec3) -> Vec3,
    transmittance: impl Fn(f32) -> Vec3,
) -> Option<ShadowQuery> {
    let lights = &scene.lights;
    let (ls, unshadowed, pmf) = if lights.punctual_per_point {
        // What each lamp sends here, unshadowed: the value this sample returns when visible.
        let c = choose_by_contribution(&lights.punctual, at.p, at.u_select, |ls| {
            eval(ls.wi) * ls.li * transmittance(ls.dist)
        })?;
        (c.sample, c.contribution, c.pmf)
    } else {
        let (light, pmf) = lights.choose_punctual(at.p, at.ng, at.u_select)?;
        let ls = light.sample_li(at.p)?;
        let f = eval(ls.wi);
        if is_black(f) {
            return None;
        }
        (ls, f * ls.li * transmittance(ls.dist), pmf)
    };
    Some(lamp_shadow(at, &ls, unshadowed / pmf))
}

/// The shadow ray of lamp sample `ls` at `at`, which adds `value` if the lamp is visible.
#[inline(always)]
pub(crate) fn lamp_shadow(at: &PunctualAt, ls: &PunctualSample, value: Vec3) -> ShadowQuery {
    let t_max = if ls.dist.is_finite() {
        ls.dist * (1.0 - SHADOW_EPSILON)
    } else {
        f32::INFINITY
    };
    ShadowQuery {
        ray: spawn(at.p, at.ng, at.clearance, ls.wi),
        t_max,
        alpha_u: at.alpha_u,
        value,
    }
}

/// A shadow ray whose answer is still to come, and what it adds to the path's radiance if the
/// light is visible.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ShadowQuery {
    pub ray: Ray,
    pub t_max: f32,
    pub alpha_u: f32,
    /// The contribution if unoccluded, before the path throughput is applied.
    pub value: Vec3,
}

/// The vertex's light sample for the area lights and the environment: the environment with
/// probability `environment_choice` (the selection number is remapped to choose among the area
/// lights otherwise, so no dimension is added), each sample's density including the probability of
/// its family. Without an environment this is [`area_light_query`] with `u_sel` as it was drawn.
#[inline(always)]
pub(crate) fn light_query(
    scene: &Scene,
    v: &Vertex,
    s: &PixelSampler,
    depth: u32,
    mis: bool,
) -> Option<ShadowQuery> {
    let u_sel = s.bounce1(depth, dims::LIGHT_SELECT);
    let lights = &scene.lights;
    let Some(env) = lights.sampled_environment() else {
        return area_light_query(scene, v, s, depth, mis, u_sel, 1.0);
    };
    let p_env = lights.environment_choice;
    if u_sel >= p_env {
        let u = ((u_sel - p_env) / lights.area_choice).min(1.0 - f32::EPSILON / 2.0);
        return area_light_query(scene, v, s, depth, mis, u, lights.area_choice);
    }
    let es = env.sample(s.bounce2(depth, dims::LIGHT_POINT))?;
    let pdf = p_env * es.pdf;
    let (f, bsdf_pdf) = if mis {
        v.eval_pdf(es.wi)
    } else {
        (v.bsdf.eval(v.wo, es.wi), 0.0)
    };
    let value = environment_value(es.radiance, pdf, f, bsdf_pdf, mis)?;
    Some(ShadowQuery {
        ray: v.spawn(es.wi),
        t_max: f32::INFINITY,
        alpha_u: s.bounce1(depth, dims::ALPHA),
        value,
    })
}

/// What the environment's light sample contributes if its shadow ray is clear: f · L / pdf, with
/// the power-heuristic weight under `mis`, for a direction drawn with density `pdf` (its family's
/// choice included) bringing radiance `radiance`, where the BSDF gives `f` (and `bsdf_pdf`).
/// None when it contributes nothing. As [`LightGeometry::value`], everything is computed before
/// anything is rejected: the wavefront's lanes call it in a vector loop.
#[inline(always)]
pub(crate) fn environment_value(
    radiance: Vec3,
    pdf: f32,
    f: Vec3,
    bsdf_pdf: f32,
    mis: bool,
) -> Option<Vec3> {
    let w = if mis {
        power_heuristic(pdf, bsdf_pdf)
    } else {
        1.0
    };
    let value = f * radiance * (w / pdf);
    let valid = !is_black(f) & !is_black(radiance) & (pdf > 0.0) & pdf.is_finite();
    valid.then_some(value)
}

/// A point on an area light chosen for the vertex (from `u_sel`, by power or by the light tree; the
/// family was chosen with probability `choice`), pdf choice · P(light)/A converted to solid angle by
/// r² / |cos θ'|. With `mis`,
/// weighted by the power heuristic against the BSDF. Returns the shadow ray that decides the
/// contribution, untraced: the integrator traces it together with the path's continuation ray
/// (`Scene::intersect_and_visible`). None when the sample contributes nothing.
#[inline(always)]
fn area_light_query(
    scene: &Scene,
    v: &Vertex,
    s: &PixelSampler,
    depth: u32,
    mis: bool,
    u_sel: f32,
    choice: f32,
) -> Option<ShadowQuery> {
    let ls = scene
        .lights
        .area
        .sample(v.p, v.ng, u_sel, s.bounce2(depth, dims::LIGHT_POINT))?;
    let tri = ls.triangle as usize;
    let material = &scene.materials[scene.mesh.material[tri] as usize];
    let g = LightGeometry::new(v.p, ls.point, ls.normal);
    let uv = light_uv(scene, tri, ls.barycentrics);
    let le = material.emission(&scene.textures, &uv, g.cos_l > 0.0);
    // With MIS the BSDF's pdf is needed too: evaluate both in one pass over the lobes.
    let (f, bsdf_pdf) = if mis {
        v.eval_pdf(g.wi)
    } else {
        (v.bsdf.eval(v.wo, g.wi), 0.0)
    };
    let value = g.value(
        ls.pdf_area * choice,
        le,
        f,
        bsdf_pdf,
        v.transmittance(g.dist),
        mis,
    )?;
    let origin = v.spawn(g.wi).o;
    let (d, t_max) = LightGeometry::shadow_segment(origin, ls.point);
    Some(ShadowQuery {
        ray: Ray::new(origin, d),
        t_max,
        alpha_u: s.bounce1(depth, dims::ALPHA),
        value,
    })
}

/// Where a light point lies as seen from a vertex at `p`. Shared, with [`LightGeometry::value`], by
/// [`area_light_query`] and the wavefront integrator's lanes.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LightGeometry {
    /// Unit direction to the point.
    pub wi: Vec3,
    pub dist: f32,
    pub dist2: f32,
    /// Cosine at the light (positive: `p` is on the light's front side).
    pub cos_l: f32,
}

impl LightGeometry {
    #[inline(always)]
    pub(crate) fn new(p: Vec3, point: Vec3, normal: Vec3) -> Self {
        let d = point - p;
        let dist2 = d.length_squared();
        let dist = dist2.sqrt();
        let wi = d / dist;
        let cos_l = -wi.dot(normal);
        LightGeometry {
            wi,
            dist,
            dist2,
            cos_l,
        }
    }

    /// The shadow ray's direction and t_max from `origin` (the vertex's spawned origin, moved off
    /// its surface towards the light) to the light `point`, ending [`SHADOW_EPSILON`] short of it.
    /// The segment is taken from the moved origin, not along `wi` from the vertex for `dist`: the
    /// origin's offset is measured from the vertex's own surface, and on a path that meets the
    /// light obliquely and close by it would otherwise carry the segment past the light's surface,
    /// which would then block its own light (a ceiling just above a two-sided lamp panel got no
    /// light-sampled light).
    #[inline(always)]
    pub(crate) fn shadow_segment(origin: Vec3, point: Vec3) -> (Vec3, f32) {
        let d = point - origin;
        let dist = d.length();
        (d / dist, dist * (1.0 - SHADOW_EPSILON))
    }

    /// What the light sample contributes if its shadow ray is clear: f · Le · T / pdf, with the
    /// power-heuristic weight under `mis`, for a point drawn with area density `pdf_area`, emitting
    /// `le` towards the vertex, where the BSDF gives `f` (and `bsdf_pdf`) and the medium `T`.
    /// None when it contributes nothing. Everything is computed before anything is rejected, and
    /// no closure is called: that is what lets the wavefront's loop over its lanes be vectorised.
    #[inline(always)]
    pub(crate) fn value(
        &self,
        pdf_area: f32,
        le: Vec3,
        f: Vec3,
        bsdf_pdf: f32,
        transmittance: Vec3,
        mis: bool,
    ) -> Option<Vec3> {
        let pdf = pdf_area * self.dist2 / self.cos_l.abs();
        let w = if mis {
            power_heuristic(pdf, bsdf_pdf)
        } else {
            1.0
        };
        let value = f * le * transmittance * (w / pdf);
        let valid = self.dist2 > 0.0
            && self.cos_l != 0.0
            && !is_black(le)
            && !is_black(f)
            && pdf > 0.0
            && pdf.is_finite();
        valid.then_some(value)
    }
}

/// The texture coordinates of a light sample on triangle `tri` of the world-space mesh at
/// barycentrics `b` (for an emissive texture; shared with the wavefront's lanes).
#[inline]
pub(crate) fn light_uv(scene: &Scene, tri: usize, b: Vec3) -> [Vec2; 2] {
    let interp = |t: &[Vec2; 3]| t[0] * b.x + t[1] * b.y + t[2] * b.z;
    [
        scene
            .mesh
            .uv0
            .as_ref()
            .map_or(Vec2::ZERO, |u| interp(&u[tri])),
        scene
            .mesh
            .uv1
            .as_ref()
            .map_or(Vec2::ZERO, |u| interp(&u[tri])),
    ]
}

/// Direct lighting by sampling a direction (uniform or cosine-weighted about the geometric normal on
/// the viewer's side) and tracing it to whatever emitter it hits, or to the environment if it
/// leaves the scene. On surfaces that transmit through a
/// non-delta lobe both hemispheres are sampled, each with probability ½, so light from behind is not
/// missed.
pub(crate) fn direct_by_direction(
    scene: &Scene,
    v: &Vertex,
    s: &PixelSampler,
    depth: u32,
    strategy: DirectStrategy,
    rays: &mut u32,
) -> Vec3 {
    let mut n = if v.wo.dot(v.ng) >= 0.0 { v.ng } else { -v.ng };
    let mut side_pdf = 1.0;
    if v.bsdf.has_non_delta_transmission() {
        side_pdf = 0.5;
        if s.bounce1(depth, dims::DIRECT_SIDE) < 0.5 {
            n = -n;
        }
    }
    let u = s.bounce2(depth, dims::DIRECT_DIR);
    let (local, pdf) = match strategy {
        DirectStrategy::Cosine => {
            let w = sample_cosine_hemisphere(u);
            (w, cosine_hemisphere_pdf(w.z))
        }
        _ => (sample_uniform_hemisphere(u), uniform_hemisphere_pdf()),
    };
    let pdf = pdf * side_pdf;
    if pdf <= 0.0 {
        return Vec3::ZERO;
    }
    let wi = Frame::from_z(n).to_world(local);
    let f = v.bsdf.eval(v.wo, wi);
    if is_black(f) {
        return Vec3::ZERO;
    }
    let ray = v.spawn(wi);
    *rays += 1;
    let Some(hit) = scene.intersect(&ray, f32::INFINITY, s.bounce1(depth, dims::ALPHA)) else {
        return match &scene.lights.environment {
            Some(env) => f * env.radiance(wi) / pdf,
            None => Vec3::ZERO,
        };
    };
    let si = scene.surface(&ray, &hit);
    let material = &scene.materials[si.material as usize];
    if !material.is_emissive() {
        return Vec3::ZERO;
    }
    let le = material.emission(&scene.textures, &si.uv, si.front);
    f * le * v.transmittance(hit.t) / pdf
}
