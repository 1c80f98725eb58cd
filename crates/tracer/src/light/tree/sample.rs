//! The walk: choosing a light for a shading point, and the probability of that choice.

use super::node::Node4;
use super::{LightTree, ONE_BELOW};
use glam::{Vec3, Vec4};

/// Where a walk's step leads: down to a node, or to its end (the light and its probability, or
/// None).
enum Step<'t> {
    Down(&'t Node4),
    Done(Option<(usize, f32)>),
}

impl LightTree {
    /// Chooses a light for the point `p` with unit normal `n` (zero: none) from `u` in [0, 1).
    /// Returns its index and probability, or None when no light reaches `p`.
    #[inline]
    pub fn sample(&self, p: Vec3, n: Vec3, mut u: f32) -> Option<(usize, f32)> {
        let (mut node, mut pmf) = (self.nodes.first()?, 1.0f32);
        loop {
            match self.step::<true>(node, p, n, &mut u, &mut pmf) {
                Step::Down(next) => node = next,
                Step::Done(chosen) => return chosen,
            }
        }
    }

    /// [`LightTree::sample`] for `M` points at once, the same answers: the walks step by turns,
    /// so that the processor works on the others while one waits on its node's importances (each
    /// step waits on the one before).
    #[inline]
    pub fn sample_many<const M: usize>(
        &self,
        queries: [(Vec3, Vec3, f32); M],
    ) -> [Option<(usize, f32)>; M] {
        let Some(root) = self.nodes.first() else {
            return [None; M];
        };
        let mut nodes = [root; M];
        let mut u = queries.map(|q| q.2);
        let mut pmf = [1.0f32; M];
        let (mut chosen, mut live) = ([None; M], [true; M]);
        while live.iter().any(|&l| l) {
            for w in 0..M {
                if live[w] {
                    let (p, n, _) = queries[w];
                    match self.step::<false>(nodes[w], p, n, &mut u[w], &mut pmf[w]) {
                        Step::Down(next) => nodes[w] = next,
                        Step::Done(c) => (chosen[w], live[w]) = (c, false),
                    }
                }
            }
        }
        chosen
    }

    /// One step of a walk at `node`: the child chosen by `u` (rescaled for the steps below) and its
    /// probability multiplied into `pmf`. `BRANCHY`: the child chosen by a branch a child (for a
    /// lone walk) or by lane masks (for walks side by side); the same child either way.
    #[inline(always)]
    fn step<'t, const BRANCHY: bool>(
        &'t self,
        node: &'t Node4,
        p: Vec3,
        n: Vec3,
        u: &mut f32,
        pmf: &mut f32,
    ) -> Step<'t> {
        self.prefetch_children(node);
        let importances = node.importances(p, n);
        let i = importances.to_array();
        // The running sums in lane order; the last is the sum `probabilities` divides by (the
        // same bits: adding a lane's zero changes no sum).
        let below = [0.0, i[0], i[0] + i[1], i[0] + i[1] + i[2]];
        let sum = below[3] + i[3];
        if !(sum > 0.0 && sum.is_finite()) {
            return Step::Done(None);
        }
        // The first child that can be chosen whose share of [0, sum) holds u · sum: the
        // importances compared as they are, so that the next step waits on no division by the
        // sum (the probability, which the choice does not wait for, divides). Rounding can
        // leave u · sum past the last share, which then goes to the last child that can be
        // chosen.
        let target = *u * sum;
        let count = node.count as usize;
        let k = if BRANCHY {
            // A branch a child: the processor guesses past it (a lone walk gains).
            let mut k = usize::MAX;
            for (j, &ij) in i.iter().enumerate().take(count) {
                if ij > 0.0 {
                    k = j;
                    if target < below[j] + ij {
                        break;
                    }
                }
            }
            k
        } else {
            // Lane masks (a compare, a bit scan): nothing to mispredict, which would discard
            // the walks beside this one too.
            let running = Vec4::from_array(below) + importances;
            let open = importances.cmpgt(Vec4::ZERO).bitmask() & ((1 << count) - 1);
            let holds = Vec4::splat(target).cmplt(running).bitmask() & open;
            (if holds != 0 {
                holds.trailing_zeros()
            } else {
                31u32.saturating_sub(open.leading_zeros())
            }) as usize
        };
        let below = below[k];
        let ik = i[k];
        *u = ((target - below).max(0.0) / ik).min(ONE_BELOW);
        // `probabilities`' quotient, the same bits as `pmf` multiplies.
        let pk = ik / sum;
        if pk == 0.0 {
            // A share below the smallest float, reached only by rounding past the others.
            return Step::Done(None);
        }
        *pmf *= pk;
        match node.slots[k].light() {
            Some(light) => Step::Done(Some((light, *pmf))),
            None => Step::Down(&self.nodes[node.slots[k].0 as usize]),
        }
    }

    /// Asks the cache for the inner children of `node`, one of which the walk opens next: their
    /// loads then overlap the importances that choose among them.
    #[inline(always)]
    fn prefetch_children(&self, node: &Node4) {
        #[cfg(target_arch = "x86_64")]
        for slot in &node.slots[..node.count as usize] {
            if slot.light().is_none() {
                if let Some(child) = self.nodes.get(slot.0 as usize) {
                    let at = (child as *const Node4).cast::<i8>();
                    for line in (0..std::mem::size_of::<Node4>()).step_by(64) {
                        // SAFETY: a prefetch is a hint; it neither faults nor changes memory.
                        unsafe {
                            std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                                at.wrapping_add(line),
                            )
                        };
                    }
                }
            }
        }
    }

    /// The probability that [`LightTree::sample`] chooses light `light` at (`p`, `n`): the same
    /// probabilities multiplied in the same order, so the same bits.
    #[inline]
    pub fn pmf(&self, p: Vec3, n: Vec3, light: usize) -> f32 {
        let (Some(mut node), Some(&trail)) = (self.nodes.first(), self.trails.get(light)) else {
            return 0.0;
        };
        let (mut pmf, mut trail) = (1.0f32, trail);
        loop {
            let Some(probs) = node.probabilities(p, n) else {
                return 0.0;
            };
            let k = (trail & 3) as usize;
            trail >>= 2;
            pmf *= probs[k];
            match node.slots[k].light() {
                Some(_) => return pmf,
                None => node = &self.nodes[node.slots[k].0 as usize],
            }
        }
    }
}
