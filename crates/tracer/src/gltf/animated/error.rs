//! What can be wrong with a file's animations, skins and morph targets. Every message names the
//! animation and channel, the skin, or the mesh and primitive at fault (with their indices and
//! names), and the node they act on.

/// Why an animated scene cannot be loaded, or built at a time.
#[derive(Debug, thiserror::Error)]
pub enum AnimationError {
    /// A sampler's keyframes are unusable (no keys, times not increasing, output count).
    #[error("{channel}: {reason}")]
    Keyframes { channel: String, reason: String },
    /// The sampler's interpolation is none of LINEAR, STEP, CUBICSPLINE.
    #[error("{channel}: unknown interpolation (LINEAR, STEP or CUBICSPLINE)")]
    Interpolation { channel: String },
    /// An animated node must be given by translation, rotation and scale.
    #[error("{channel}: the node has a matrix; glTF animates only nodes given by translation, rotation and scale")]
    MatrixNode { channel: String },
    /// A skin's inverseBindMatrices do not match its joints.
    #[error("{skin}: inverseBindMatrices has {matrices} matrices for {joints} joints")]
    BindMatrices {
        skin: String,
        matrices: usize,
        joints: usize,
    },
    /// A joint that the scene's hierarchy does not reach has no world transform.
    #[error("{skin}: joint {joint} ({node}) is not in the rendered scene")]
    JointOutsideScene {
        skin: String,
        joint: usize,
        node: String,
    },
    /// A vertex names a joint the skin does not have.
    #[error("{primitive} (skinned by {skin}): {attribute} of vertex {vertex} names joint {joint}, but the skin has {joints} joints")]
    JointIndex {
        primitive: String,
        skin: String,
        attribute: String,
        vertex: usize,
        joint: f32,
        joints: usize,
    },
    /// Per-vertex data whose count is not the primitive's vertex count.
    #[error("{primitive}: {attribute} has {got} elements but POSITION has {vertices}")]
    VertexCount {
        primitive: String,
        attribute: String,
        got: usize,
        vertices: usize,
    },
    /// The primitives of a mesh disagree on their number of morph targets.
    #[error("{mesh}: primitive {primitive} has {got} morph targets, primitive 0 has {expected}")]
    TargetCount {
        mesh: String,
        primitive: usize,
        got: usize,
        expected: usize,
    },
    /// The scene cannot be built at this time (a node transform, a coordinate out of range).
    #[error("at time {time} s: {reason}")]
    AtTime { time: f32, reason: String },
}
