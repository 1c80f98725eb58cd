//! A light tree: chooses among many emitters in proportion to an estimate of what each sends to the
//! shading point, rather than to its power alone (pbrt-v4's `BVHLightSampler`, after Conty Estevez
//! and Kulla, "Importance Sampling of Many Lights with Adaptive Tree Splitting", 2018).
//!
//! Each node bounds its lights: a box, their summed power, and a cone of their normals
//! ([`LightBounds`]). The tree is built binary (split by pbrt-v4's surface area orientation
//! heuristic) and collapsed into 4-wide nodes whose children's bounds sit side by side, so that one
//! pass of vector arithmetic gives all four importances (a binary walk over an icosphere of 20k
//! emitters cost more time than its better choices saved). A sample walks from the root, at every
//! node choosing a child in proportion to its importance at the shading point (power over squared
//! distance, times bounds on the cosines at the light and at the receiver), and reaches one light
//! with the product of those choices as its probability. [`LightTree::pmf`] retraces the same
//! choices from the light's trail (two bits per level: the child slot), with the same arithmetic in
//! the same order, so the probability a BSDF-sampled ray's MIS weight uses is bit for bit the one
//! light sampling drew with.
//!
//! Unbiased: importance is a conservative bound, zero only where no light of the node can send
//! light to the point (behind every one-sided emitter of the node, or beyond the horizon of the
//! receiver's plane for every direction in the node's box); nodes of zero importance are never
//! chosen and nothing they could contribute is lost. A node's bounds are looser than its
//! children's, so a node may be chosen whose children are all out of reach: the sample then finds
//! no light (the probabilities of all lights sum to at most 1), which wastes the sample but
//! loses nothing that light could have sent. Deterministic: the build is sequential and
//! uses only IEEE arithmetic and `math::det`'s functions, so the tree, and every probability, has
//! the same bits on every machine.

mod bounds;
mod build;
mod node;
mod sample;
#[cfg(test)]
mod tests;

pub(crate) use bounds::LightBounds;
use node::Node4;

#[inline(always)]
fn safe_sqrt(x: f32) -> f32 {
    x.max(0.0).sqrt()
}

/// The largest f32 below 1.
pub(super) const ONE_BELOW: f32 = 1.0 - f32::EPSILON / 2.0;

/// A light tree over a scene's emitters (see the module documentation).
#[derive(Clone, Debug, Default)]
pub struct LightTree {
    /// Root first.
    nodes: Vec<Node4>,
    /// Per light: the path from the root to it, two bits per level (the child slot).
    trails: Vec<u128>,
}
