//! What a job is rendered with: [`JobSettings`], its environment light and its frame order.

use super::{by_name, integer};
use pathfarm_tracer::{DirectStrategy, RenderSettings, RussianRoulette, SamplerKind};
use serde::{Deserialize, Serialize};

fn default_tile() -> u32 {
    64
}

fn one() -> f32 {
    1.0
}

/// A job's environment light: radiance from every direction a ray leaves the scene in, what
/// `pathfarm render --environment` gives a local render. Exactly one of `radiance` (one linear
/// colour) and `image` (the SHA-256 of an equirectangular OpenEXR or Radiance `.hdr` image the
/// server stores: uploaded as the submission's `environment` part, which sets it, or one it already
/// has). [`EnvironmentSettings::build`] makes the tracer's environment from it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvironmentSettings {
    /// Linear RGB radiance, the same from every direction.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radiance: Option<[f32; 3]>,
    /// Lowercase hexadecimal SHA-256 of the image's bytes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<String>,
    /// Multiplies the radiance (`--environment-strength`).
    #[serde(default = "one")]
    pub strength: f32,
    /// Turns the image about the up axis (`--environment-rotation`).
    #[serde(default)]
    pub rotation_degrees: f32,
}

impl Default for EnvironmentSettings {
    fn default() -> Self {
        EnvironmentSettings {
            radiance: None,
            image: None,
            strength: 1.0,
            rotation_degrees: 0.0,
        }
    }
}

/// Everything a job is rendered with besides its scene: the JSON `settings` part of a submission.
/// The render-relevant fields mean exactly what the same `pathfarm render` flags mean, so a farm job
/// and a local render with equal settings give bit-identical images.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobSettings {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(deserialize_with = "integer::deserialize")]
    pub width: u32,
    #[serde(deserialize_with = "integer::deserialize")]
    pub height: u32,
    /// Samples (camera paths) per pixel.
    #[serde(deserialize_with = "integer::deserialize")]
    pub spp: u32,
    #[serde(default, deserialize_with = "integer::deserialize")]
    pub seed: u64,
    /// Tile edge in pixels (does not change the image).
    #[serde(default = "default_tile", deserialize_with = "integer::deserialize")]
    pub tile_size: u32,
    #[serde(default, with = "by_name")]
    pub direct: DirectStrategy,
    #[serde(default, with = "by_name")]
    pub rr: RussianRoulette,
    /// Maximum bounces; absent is unlimited (unbiased).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "integer::option::deserialize"
    )]
    pub max_depth: Option<u32>,
    #[serde(default, with = "by_name")]
    pub sampler: SamplerKind,
    /// Camera name; absent: the scene's first camera.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<String>,
    /// Higher runs first.
    #[serde(default, deserialize_with = "integer::deserialize")]
    pub priority: i32,
    /// Stop once the estimated relative error of the image falls below this (e.g. 0.02).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_target: Option<f64>,
    /// Stop after this many seconds of rendering.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_limit_s: Option<f64>,
    /// The environment light; absent: none (rays that escape see black).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub environment: Option<EnvironmentSettings>,
    /// Frames of the scene's animation to render, one image each (`1-240`, `1-240x2`,
    /// `1,5,10-12`: [`crate::frames::parse_frames`]); absent: one still image, as before.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<String>,
    /// Frames per second of `frames`: frame f is rendered at time f / fps (what
    /// `pathfarm render --frame f --fps fps` renders); absent: 24.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fps: Option<f64>,
    /// The order in which a frame job's frames are rendered; absent: interleaved.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_order: Option<FrameOrder>,
}

/// How a frame job's tasks are ordered.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FrameOrder {
    /// Every frame gets each pass before any frame gets the next: all frames sharpen together.
    #[default]
    Interleaved,
    /// Frame by frame, in the order written: each frame is finished before the next starts.
    Sequential,
}

impl JobSettings {
    /// Settings with the defaults of `pathfarm render`.
    pub fn new(width: u32, height: u32, spp: u32) -> Self {
        JobSettings {
            name: None,
            width,
            height,
            spp,
            seed: 0,
            tile_size: default_tile(),
            direct: DirectStrategy::default(),
            rr: RussianRoulette::default(),
            max_depth: None,
            sampler: SamplerKind::default(),
            camera: None,
            priority: 0,
            noise_target: None,
            time_limit_s: None,
            environment: None,
            frames: None,
            fps: None,
            frame_order: None,
        }
    }

    /// The frames of a frame job (`None` for a still job), as [`crate::frames::parse_frames`]
    /// reads `frames`.
    pub fn frame_list(&self) -> Result<Option<Vec<i64>>, crate::frames::FrameSpecError> {
        self.frames
            .as_deref()
            .map(crate::frames::parse_frames)
            .transpose()
    }

    /// Frames per second of a frame job: `fps`, or 24.
    pub fn frames_per_second(&self) -> f64 {
        self.fps.unwrap_or(pathfarm_tracer::gltf::DEFAULT_FPS)
    }

    /// The tracer's settings (what determines the bits of the image).
    pub fn render_settings(&self) -> RenderSettings {
        RenderSettings {
            width: self.width,
            height: self.height,
            seed: self.seed,
            direct: self.direct,
            rr: self.rr,
            max_depth: self.max_depth,
            sampler: self.sampler,
        }
    }
}
