//! Animated scenes: glTF animation channels on node translation, rotation and scale (nodes carrying
//! meshes, cameras and KHR_lights_punctual lamps alike) and on morph-target weights, and skins,
//! with LINEAR, STEP and CUBICSPLINE interpolation (`interpolate.rs`), evaluated at a time t in
//! seconds; a frame f at r frames per second is t = f / r ([`frame_time`]).
//!
//! The file is parsed and its geometry read once, into an [`AnimatedScene`]; [`AnimatedScene::scene_at`]
//! builds the [`Scene`] at a time from it without touching the bytes again, and rebuilds only what
//! moves (see `frame.rs`): what does not move between frames — the still meshes and their BVHs, the
//! textures — is built once and shared (`Arc`) by every frame's scene.
//!
//! A still file (no animations) pays nothing: [`SceneSource::load`] hands it to the still loader
//! ([`super::load`]), and [`super::load`] itself renders every file at rest, as before.
//!
//! Which animation plays: **all channels of all animations, together** (Blender exports one
//! animation per action; see `channels.rs`). Times before the first key take the first key's
//! values, after the last the last's. The scene's time span ([`AnimatedScene::time_span`]) runs
//! from the earliest key of any channel to the latest; [`TimeSpan::frames`] gives the frames it
//! covers at a frame rate.
//!
//! Morph targets and skins are applied only here: the still loader renders base geometry and
//! bind poses, with a warning.

mod channels;
mod deform;
mod error;
mod frame;
mod interpolate;
mod load;
mod pose;
mod skin;

pub use error::AnimationError;

use super::document;
use super::emit::LocalPrimitive;
use super::mesh::Needs;
use super::{guarded, GltfError, LoadOptions, ResourceResolver};
use crate::geometry::Prototype;
use crate::material::{Material, Texture};
use crate::scene::{Scene, World};
use channels::Channel;
use deform::Deformable;
use glam::DMat4;
use gltf::json;
use pose::Hierarchy;
use skin::Skin;
use std::borrow::Cow;
use std::sync::Arc;

/// Frames per second when nothing else is said (film's rate, Blender's default).
pub const DEFAULT_FPS: f64 = 24.0;

/// The time of frame `frame` at `fps` frames per second: frame / fps, in seconds (computed in
/// f64, rounded once to f32). Every renderer of a frame (local or on the farm) goes through this.
pub fn frame_time(frame: i64, fps: f64) -> f32 {
    (frame as f64 / fps) as f32
}

/// The span of an animation's keys, in seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeSpan {
    pub start: f32,
    pub end: f32,
}

impl TimeSpan {
    /// The first and last frames at `fps` (the nearest frames to the span's ends: keys exported
    /// at frame f lie at f / fps up to rounding). Blender exports frame f at f / fps, so a
    /// timeline of frames 1–250 gives 1..=250.
    pub fn frames(&self, fps: f64) -> std::ops::RangeInclusive<i64> {
        let at = |t: f32| (t as f64 * fps).round() as i64;
        at(self.start)..=at(self.end)
    }
}

/// What an animation does to a scene's nodes: which move (their world transform is animated, by
/// a channel on them or an ancestor) and which deform their mesh (skinned, or with morph
/// targets). The default, nothing, is a still scene's.
#[derive(Clone, Debug, Default)]
pub(crate) struct Motion {
    moving: Vec<bool>,
    deforming: Vec<bool>,
    animated: bool,
}

impl Motion {
    /// Whether the scene is loaded at a time of its animation.
    pub fn is_animated(&self) -> bool {
        self.animated
    }

    /// Whether node `node`'s world transform changes with time.
    pub fn moves(&self, node: usize) -> bool {
        self.moving.get(node).copied().unwrap_or(false)
    }

    /// Whether node `node`'s mesh is deformed (skinned or morphed).
    pub fn deforms(&self, node: usize) -> bool {
        self.deforming.get(node).copied().unwrap_or(false)
    }
}

/// The world-space triangles: built once, or (when an emitter moves) the still ones kept to be
/// built with the moving ones at each frame.
#[derive(Clone, Debug)]
enum WorldSource {
    Shared(World),
    PerFrame(crate::geometry::Mesh),
}

/// A placement of an instanced mesh: its node's world transform at a time (times the instancing
/// row's transform, for EXT_mesh_gpu_instancing).
#[derive(Clone, Debug)]
struct PlacementSource {
    prototype: u32,
    node: usize,
    row: Option<DMat4>,
}

/// A node whose mesh the animation deforms.
#[derive(Clone, Debug)]
struct DeformedNode {
    node: usize,
    mesh: usize,
    /// Index into `AnimatedScene::skins`.
    skin: Option<usize>,
    /// Some primitive's material may emit: its triangles go to the world-space mesh.
    emits: bool,
    /// EXT_mesh_gpu_instancing rows (a morphed mesh is placed by each; skinning ignores them).
    rows: Option<Vec<DMat4>>,
    primitives: Vec<Deformable>,
}

/// A moving node's emissive mesh (emitters are world-space triangles).
#[derive(Clone, Debug)]
struct MovingEmitter {
    node: usize,
    mesh: usize,
    /// EXT_mesh_gpu_instancing rows: the mesh is placed by each.
    rows: Option<Vec<DMat4>>,
    primitives: Vec<LocalPrimitive>,
}

/// The transforms a node at `world` places its mesh at: one per instancing row, or `world`.
fn placed(world: DMat4, rows: &Option<Vec<DMat4>>) -> Vec<DMat4> {
    match rows {
        None => vec![world],
        Some(rows) => rows.iter().map(|row| world * *row).collect(),
    }
}

/// An animated glTF scene, loaded once; [`AnimatedScene::scene_at`] builds it at any time.
/// Shareable between threads.
#[derive(Clone, Debug)]
pub struct AnimatedScene {
    root: json::Root,
    channels: Vec<Channel>,
    hierarchy: Hierarchy,
    skins: Vec<Skin>,
    materials: Vec<Material>,
    textures: Arc<[Texture]>,
    world: WorldSource,
    /// Every instanced mesh, its BVH built.
    prototypes: Vec<Arc<Prototype>>,
    placements: Vec<PlacementSource>,
    deformed: Vec<DeformedNode>,
    emitters: Vec<MovingEmitter>,
    /// The nodes carrying a KHR_lights_punctual light, in traversal order.
    lights: Vec<usize>,
    /// The camera's node and index.
    camera: Option<(usize, usize)>,
    needs: Needs,
    warnings: Vec<String>,
    /// Degenerate triangles dropped at load.
    dropped: usize,
}

/// A node's translation, rotation (x, y, z, w) and scale at a time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NodeTrs {
    pub translation: [f32; 3],
    pub rotation: [f32; 4],
    pub scale: [f32; 3],
}

impl AnimatedScene {
    /// Loads an animated glTF or GLB file (one with animations, else it is loaded at rest all
    /// the same: its skins and morph targets applied).
    pub fn load(
        bytes: &[u8],
        resolver: &dyn ResourceResolver,
        options: &LoadOptions,
    ) -> Result<AnimatedScene, GltfError> {
        guarded(|| load::load(document::parse(bytes)?, resolver, options))
    }

    /// The scene at `time` seconds. Fails only where the animation makes the scene unusable at
    /// that time (a zero-length rotation, a coordinate beyond the loader's range).
    pub fn scene_at(&self, time: f32) -> Result<Scene, GltfError> {
        guarded(|| self.build_at(time))
    }

    /// From the earliest key of any channel to the latest; `None` without channels.
    pub fn time_span(&self) -> Option<TimeSpan> {
        let mut span: Option<TimeSpan> = None;
        for c in &self.channels {
            let (start, end) = c.keys.span();
            span = Some(match span {
                None => TimeSpan { start, end },
                Some(s) => TimeSpan {
                    start: s.start.min(start),
                    end: s.end.max(end),
                },
            });
        }
        span
    }

    /// The load's warnings.
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// Node `node`'s translation, rotation and scale at `time`, for a node that a channel
    /// animates (`None` otherwise).
    pub fn node_trs_at(&self, node: usize, time: f32) -> Option<NodeTrs> {
        self.hierarchy
            .trs_at(&self.channels, node, time)
            .map(|t| NodeTrs {
                translation: t.translation,
                rotation: t.rotation,
                scale: t.scale,
            })
    }

    /// Whether each frame builds the world-space triangles' BVH again (some emitter moves or
    /// deforms); otherwise every frame shares the one built at load.
    pub fn world_rebuilt_per_frame(&self) -> bool {
        matches!(self.world, WorldSource::PerFrame(_))
    }
}

/// A scene file as loaded for rendering at any time: a still file as the still loader builds it,
/// an animated one as an [`AnimatedScene`].
#[derive(Clone, Debug)]
pub enum SceneSource {
    Still(Box<Scene>),
    Animated(Box<AnimatedScene>),
}

impl SceneSource {
    /// Parses the file once: without animations it is built by the still loader (exactly
    /// [`super::load`]), with them it becomes an [`AnimatedScene`].
    pub fn load(
        bytes: &[u8],
        resolver: &dyn ResourceResolver,
        options: &LoadOptions,
    ) -> Result<SceneSource, GltfError> {
        guarded(|| {
            let parsed = document::parse(bytes)?;
            if parsed.root.animations.is_empty() {
                let parts = super::load_parsed(parsed, resolver, options)?;
                Ok(SceneSource::Still(Box::new(Scene::build(parts)?)))
            } else {
                Ok(SceneSource::Animated(Box::new(load::load(
                    parsed, resolver, options,
                )?)))
            }
        })
    }

    /// The animation's span, `None` for a still scene.
    pub fn time_span(&self) -> Option<TimeSpan> {
        match self {
            SceneSource::Still(_) => None,
            SceneSource::Animated(a) => a.time_span(),
        }
    }

    /// The scene at `time`: a still scene itself (borrowed), an animated one built.
    pub fn scene_at(&self, time: f32) -> Result<Cow<'_, Scene>, GltfError> {
        match self {
            SceneSource::Still(s) => Ok(Cow::Borrowed(s)),
            SceneSource::Animated(a) => a.scene_at(time).map(Cow::Owned),
        }
    }

    /// The scene at `time`, owned (a still scene is moved out, not copied).
    pub fn into_scene_at(self, time: f32) -> Result<Scene, GltfError> {
        match self {
            SceneSource::Still(s) => Ok(*s),
            SceneSource::Animated(a) => a.scene_at(time),
        }
    }
}
