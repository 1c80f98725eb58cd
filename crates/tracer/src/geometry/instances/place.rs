//! Placing prototypes: the placements that place something, and the tree over their instances.

use super::{Instance, InstanceError, Instances, Placement, Prototype, Unplaced};
use crate::geometry::bvh::{BoxTree, MAX_BOXES};
use crate::geometry::Mesh;
use std::sync::Arc;

/// The SAH cost of a node visit against one instance test, for the top-level tree's leaf decision:
/// with one instance a leaf it decides nothing (every range of two or more is split), and is
/// obvhs' default, which built this tree before.
const TOP_TRAVERSAL_COST: f64 = 3.0;

/// Placements that place something, each with its instance.
pub type Usable<'a> = Vec<(&'a Placement, Instance)>;

/// The placements that place something (their prototype, of `triangles[prototype]` triangles,
/// has any; their transform is invertible and finite) with their instances, and those dropped for
/// their transform: what [`Instances::place`] places, decided without building anything.
pub fn usable_placements<'a>(
    triangles: &[usize],
    placements: &'a [Placement],
) -> Result<(Usable<'a>, Unplaced), InstanceError> {
    check_placements(triangles.len(), placements)?;
    let mut usable = Vec::with_capacity(placements.len());
    let mut dropped = Unplaced::default();
    for p in placements {
        let n = triangles[p.prototype as usize];
        if n == 0 {
            continue;
        }
        match Instance::new(p.prototype, &p.to_world) {
            Some(inst) => usable.push((p, inst)),
            None => {
                dropped.placements += 1;
                dropped.triangles += n;
            }
        }
    }
    Ok((usable, dropped))
}

fn check_placements(prototypes: usize, placements: &[Placement]) -> Result<(), InstanceError> {
    match placements
        .iter()
        .enumerate()
        .find(|(_, p)| p.prototype as usize >= prototypes)
    {
        Some((instance, p)) => Err(InstanceError::Prototype {
            instance,
            prototype: p.prototype,
            count: prototypes,
        }),
        None => Ok(()),
    }
}

impl Instances {
    /// The prototypes (their BVHs built) and the placements that are usable, with the tree over
    /// them. A singular or non-finite transform drops its placement (nothing of it could be hit):
    /// the dropped placements and the triangles they would have placed are returned.
    pub fn build(
        prototypes: Vec<Mesh>,
        placements: &[Placement],
    ) -> Result<(Instances, Unplaced), InstanceError> {
        check_placements(prototypes.len(), placements)?;
        let prototypes = prototypes
            .into_iter()
            .map(|m| Arc::new(Prototype::new(m)))
            .collect();
        Self::place(prototypes, placements)
    }

    /// The instances of prototypes already built (shared with other scenes): only the tree over
    /// the placements is built. As [`Instances::build`] otherwise.
    pub fn place(
        prototypes: Vec<Arc<Prototype>>,
        placements: &[Placement],
    ) -> Result<(Instances, Unplaced), InstanceError> {
        let triangles: Vec<usize> = prototypes.iter().map(|p| p.mesh.len()).collect();
        let (usable, dropped) = usable_placements(&triangles, placements)?;
        let mut instances = Vec::with_capacity(usable.len());
        let mut boxes = Vec::with_capacity(usable.len());
        for (p, inst) in usable {
            let proto = &prototypes[p.prototype as usize];
            boxes.push(Instance::world_box(&p.to_world, &proto.cover));
            instances.push(inst);
        }
        if instances.is_empty() {
            return Ok((
                Instances {
                    prototypes,
                    ..Instances::default()
                },
                dropped,
            ));
        }
        if instances.len() >= MAX_BOXES {
            return Err(InstanceError::TooMany {
                count: instances.len(),
                max: MAX_BOXES - 1,
            });
        }
        // One instance a leaf: each placement's own box is tested before its ray is moved.
        let (tree, order) = BoxTree::build(&boxes, TOP_TRAVERSAL_COST);
        // The instances in leaf order, so that a leaf's range indexes them directly.
        let ordered: Vec<Instance> = order
            .iter()
            .map(|&i| instances[i as usize].clone())
            .collect();
        Ok((
            Instances {
                prototypes,
                instances: ordered,
                tree,
            },
            dropped,
        ))
    }
}
