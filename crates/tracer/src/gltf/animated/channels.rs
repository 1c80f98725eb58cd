//! A file's animation channels, read once: each channel's target (a node's translation, rotation,
//! scale or morph weights) and its sampler's keyframes, through the loader's bounds-checked
//! accessor reader (not the `gltf` crate's, which may panic on inconsistent files).
//!
//! **All channels of all animations play together** on one timeline: exporters write one
//! animation per action (Blender) or per object, and a shot is all of them at once. Where two
//! channels target the same property of the same node, the later one (by animation, then by
//! channel) wins. Channels on nodes outside the rendered scene are ignored; channels with a path
//! this loader does not know (an extension's) are ignored with a warning.

use super::error::AnimationError;
use super::interpolate::{Interpolation, Keyframes};
use crate::gltf::accessors::Accessors;
use crate::gltf::error::{label, GltfError, Warnings};
use crate::gltf::nodes::node_label;
use gltf::json;
use json::animation::{Interpolation as JsonInterpolation, Property};
use json::validation::Checked;

/// The property a channel animates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Target {
    Translation,
    Rotation,
    Scale,
    /// The morph target weights of the node's mesh.
    Weights,
}

impl Target {
    fn name(self) -> &'static str {
        match self {
            Target::Translation => "translation",
            Target::Rotation => "rotation",
            Target::Scale => "scale",
            Target::Weights => "weights",
        }
    }
}

/// One channel: a node's property and the keyframes that drive it.
#[derive(Clone, Debug)]
pub(crate) struct Channel {
    pub node: usize,
    pub target: Target,
    pub keys: Keyframes,
}

/// `animation 0 "Walk", channel 3 (rotation of node 5 "Arm")`.
fn channel_label(
    root: &json::Root,
    animation: usize,
    channel: usize,
    node: usize,
    path: &str,
) -> String {
    let a = root.animations.get(animation);
    format!(
        "{}, channel {channel} ({path} of {})",
        label("animation", animation, a.and_then(|a| a.name.as_deref())),
        node_label(root, node)
    )
}

/// The number of morph targets of mesh `mesh` (its first primitive's; the reader of the targets
/// checks that the others agree).
pub(crate) fn target_count(root: &json::Root, mesh: usize) -> usize {
    root.meshes
        .get(mesh)
        .and_then(|m| m.primitives.first())
        .and_then(|p| p.targets.as_ref())
        .map_or(0, Vec::len)
}

/// Every channel of every animation that acts on a node of the scene (`in_scene[node]`), in file
/// order.
pub(crate) fn read(
    acc: &Accessors<'_, '_>,
    in_scene: &[bool],
    warnings: &mut Warnings,
) -> Result<Vec<Channel>, GltfError> {
    let root = acc.root();
    let mut out = Vec::new();
    for (a, animation) in root.animations.iter().enumerate() {
        for (c, channel) in animation.channels.iter().enumerate() {
            let node = channel.target.node.value();
            if !in_scene.get(node).copied().unwrap_or(false) {
                continue;
            }
            let target = match channel.target.path {
                Checked::Valid(Property::Translation) => Target::Translation,
                Checked::Valid(Property::Rotation) => Target::Rotation,
                Checked::Valid(Property::Scale) => Target::Scale,
                Checked::Valid(Property::MorphTargetWeights) => Target::Weights,
                Checked::Invalid => {
                    warnings.once(format!(
                        "{}: unknown target path; channel ignored",
                        channel_label(root, a, c, node, "a property")
                    ));
                    continue;
                }
            };
            let what = channel_label(root, a, c, node, target.name());
            let Some(json_node) = root.nodes.get(node) else {
                continue;
            };
            let width = match target {
                Target::Translation | Target::Scale => 3,
                Target::Rotation => 4,
                Target::Weights => {
                    let n = json_node.mesh.map_or(0, |m| target_count(root, m.value()));
                    if n == 0 {
                        warnings.once(format!(
                            "{what}: the node has no mesh with morph targets; channel ignored"
                        ));
                        continue;
                    }
                    n
                }
            };
            if target != Target::Weights && json_node.matrix.is_some() {
                return Err(AnimationError::MatrixNode { channel: what }.into());
            }
            let Some(sampler) = animation.samplers.get(channel.sampler.value()) else {
                return Err(AnimationError::Keyframes {
                    channel: what,
                    reason: format!("sampler {} does not exist", channel.sampler.value()),
                }
                .into());
            };
            let interpolation = match sampler.interpolation {
                Checked::Valid(JsonInterpolation::Linear) => Interpolation::Linear,
                Checked::Valid(JsonInterpolation::Step) => Interpolation::Step,
                Checked::Valid(JsonInterpolation::CubicSpline) => Interpolation::CubicSpline,
                Checked::Invalid => {
                    return Err(AnimationError::Interpolation { channel: what }.into())
                }
            };
            let (input, output) = (sampler.input.value(), sampler.output.value());
            let times: Vec<f32> = acc
                .read_vec::<1>(input, &format!("input of {what}"))?
                .into_iter()
                .map(|[t]| t)
                .collect();
            let usage = format!("output of {what}");
            let values: Vec<f32> = match target {
                Target::Translation | Target::Scale => acc.read_vec::<3>(output, &usage)?.concat(),
                Target::Rotation => acc.read_vec::<4>(output, &usage)?.concat(),
                Target::Weights => acc.read_vec::<1>(output, &usage)?.concat(),
            };
            let keys = Keyframes {
                times,
                values,
                width,
                interpolation,
            };
            keys.check().map_err(|reason| AnimationError::Keyframes {
                channel: format!(
                    "{what}, sampler {} ({} interpolation; input accessor {input}, output accessor {output})",
                    channel.sampler.value(),
                    match interpolation {
                        Interpolation::Linear => "LINEAR",
                        Interpolation::Step => "STEP",
                        Interpolation::CubicSpline => "CUBICSPLINE",
                    }
                ),
                reason,
            })?;
            out.push(Channel { node, target, keys });
        }
    }
    Ok(out)
}
