//! Owen-scrambled Sobol points with hash-based nested uniform scrambling (Burley, "Practical
//! Hash-based Owen Scrambling", JCGT 2020).
//!
//! Dimensions are taken four at a time: group g = dim / 4 is a 4-D Sobol sequence whose index is
//! shuffled and whose components are Owen-scrambled with seeds hashed from (pixel key, g). Within a
//! group the points are a (0, m, 4)-style net with excellent 2-D projections for dims (0,1); across
//! groups they are decorrelated by the independent scrambles ("padding"). Everything is a pure
//! function of (pixel key, index, dim).

use super::{bits_to_unit, hash_u32};

/// Direction numbers of the first four Sobol dimensions (Joe & Kuo), bit-reversed-free form:
/// `DIRECTIONS[d][b]` is the contribution of index bit b to dimension d.
const DIRECTIONS: [[u32; 32]; 4] = build_directions();

const fn build_directions() -> [[u32; 32]; 4] {
    let mut v = [[0u32; 32]; 4];
    // Dimension 0: van der Corput, v_b = 2^(31-b).
    let mut b = 0;
    while b < 32 {
        v[0][b] = 1u32 << (31 - b);
        b += 1;
    }
    // Dimensions 1..3 from primitive polynomials (degree s, coefficients a) and initial m values.
    // (s, a, m): dim 1: x + 1 -> (1, 0, [1]); dim 2: x^2 + x + 1 -> (2, 1, [1, 3]);
    // dim 3: x^3 + x + 1 -> (3, 1, [1, 3, 1]).
    let params: [(usize, u32, [u32; 3]); 3] =
        [(1, 0, [1, 0, 0]), (2, 1, [1, 3, 0]), (3, 1, [1, 3, 1])];
    let mut d = 0;
    while d < 3 {
        let (s, a, m) = params[d];
        let mut i = 0;
        while i < 32 {
            if i < s {
                v[d + 1][i] = m[i] << (31 - i);
            } else {
                let mut x = v[d + 1][i - s] ^ (v[d + 1][i - s] >> s);
                let mut k = 1;
                while k < s {
                    x ^= ((a >> (s - 1 - k)) & 1) * v[d + 1][i - k];
                    k += 1;
                }
                v[d + 1][i] = x;
            }
            i += 1;
        }
        d += 1;
    }
    v
}

/// The generator matrix product as four byte-table lookups (the shuffled indices are full 32-bit
/// numbers, so a bit loop would always run 32 times), in bit-reversed form: `REVERSED_TABLES` maps reverse(index) to
/// reverse(sobol(index)). The nested uniform scramble works on bit-reversed values, so staying in
/// reversed form saves two of the three bit reversals per value (x86 has no bit-reverse instruction).
static REVERSED_TABLES: [[[u32; 256]; 4]; 4] = build_reversed_tables();

const fn build_reversed_tables() -> [[[u32; 256]; 4]; 4] {
    let mut t = [[[0u32; 256]; 4]; 4];
    let mut d = 0;
    while d < 4 {
        let mut k = 0;
        while k < 4 {
            let mut b = 0;
            while b < 256 {
                let mut x = 0u32;
                let mut bit = 0;
                while bit < 8 {
                    // Bit j of reverse(index) is bit 31 − j of the index.
                    if (b >> bit) & 1 != 0 {
                        x ^= DIRECTIONS[d][31 - (k * 8 + bit)].reverse_bits();
                    }
                    bit += 1;
                }
                t[d][k][b] = x;
                b += 1;
            }
            k += 1;
        }
        d += 1;
    }
    t
}

#[inline]
fn sobol_reversed(index_rev: u32, dim: usize) -> u32 {
    let t = &REVERSED_TABLES[dim];
    t[0][(index_rev & 0xff) as usize]
        ^ t[1][((index_rev >> 8) & 0xff) as usize]
        ^ t[2][((index_rev >> 16) & 0xff) as usize]
        ^ t[3][(index_rev >> 24) as usize]
}

/// Plain Sobol by the bit loop: the reference the tables are tested against.
#[cfg(test)]
fn sobol(index: u32, dim: usize) -> u32 {
    let mut x = 0;
    for (b, v) in DIRECTIONS[dim].iter().enumerate() {
        if (index >> b) & 1 != 0 {
            x ^= v;
        }
    }
    x
}

/// Laine–Karras style hash that only propagates entropy from lower to higher bits: applied to
/// bit-reversed values it is a nested uniform (Owen) scramble.
#[inline]
fn laine_karras_permutation(mut x: u32, seed: u32) -> u32 {
    x = x.wrapping_add(seed);
    x ^= x.wrapping_mul(0x6c50_b47c);
    x ^= x.wrapping_mul(0xb82f_1e52);
    x ^= x.wrapping_mul(0xc7af_e638);
    x ^= x.wrapping_mul(0x8d22_f6e6);
    x
}

#[cfg(test)]
fn nested_uniform_scramble(x: u32, seed: u32) -> u32 {
    laine_karras_permutation(x.reverse_bits(), seed).reverse_bits()
}

#[inline]
fn group_seed(pixel_key: u32, dim: u32) -> u32 {
    let group = dim >> 2;
    let group_key = match GROUP_KEYS.get(group as usize) {
        Some(&k) => k,
        None => group_key(group),
    };
    hash_u32(pixel_key ^ group_key)
}

/// The hash of a dimension group's number, mixed into every pixel's key.
const fn group_key(group: u32) -> u32 {
    hash_u32(group.wrapping_add(0x68bc_21eb))
}

/// [`group_key`] of the first groups (21 bounces), computed at compile time: one hash fewer per
/// sample value.
static GROUP_KEYS: [u32; 256] = {
    let mut t = [0u32; 256];
    let mut g = 0;
    while g < 256 {
        t[g] = group_key(g as u32);
        g += 1;
    }
    t
};

#[inline]
/// Component `component` of the group whose shuffled index, bit-reversed, is `shuffled_rev`:
/// reverse(LK(reverse(sobol(shuffled)))) computed as reverse(LK(sobol_reversed(shuffled_rev))).
fn scrambled_component(shuffled_rev: u32, group_seed: u32, component: usize) -> f32 {
    scrambled(
        shuffled_rev,
        component_seed(group_seed, component),
        component,
    )
}

/// [`scrambled_component`] given the component's seed.
#[inline]
fn scrambled(shuffled_rev: u32, comp_seed: u32, component: usize) -> f32 {
    let x_rev = sobol_reversed(shuffled_rev, component);
    bits_to_unit(reverse_high24(laine_karras_permutation(x_rev, comp_seed)))
}

/// The scramble seed of one component of a group.
#[inline]
fn component_seed(group_seed: u32, component: usize) -> u32 {
    hash_u32(group_seed ^ (component as u32 + 1).wrapping_mul(0x9e37_79b9))
}

/// `x.reverse_bits()` with its low 8 bits cleared: all that [`bits_to_unit`] keeps. x86 has no
/// bit-reverse instruction (a full reversal is a byte swap and three mask-and-shift rounds); three
/// byte-table lookups do.
#[inline]
fn reverse_high24(x: u32) -> u32 {
    (u32::from(REVERSED_BYTES[(x & 0xff) as usize]) << 24)
        | (u32::from(REVERSED_BYTES[((x >> 8) & 0xff) as usize]) << 16)
        | (u32::from(REVERSED_BYTES[((x >> 16) & 0xff) as usize]) << 8)
}

static REVERSED_BYTES: [u8; 256] = {
    let mut t = [0u8; 256];
    let mut b = 0;
    while b < 256 {
        t[b] = (b as u8).reverse_bits();
        b += 1;
    }
    t
};

/// Dimension `dim` of sample `index` for the pixel whose key is `pixel_key`, in [0, 1). Takes the
/// sample index bit-reversed (`index.reverse_bits()`), which callers compute once per sample.
// Inlined at every use: a call per sample value cost more than the value's own arithmetic.
#[inline(always)]
pub fn owen_sobol_sample(pixel_key: u32, index_rev: u32, dim: u32) -> f32 {
    let seed = group_seed(pixel_key, dim);
    // The shuffled index is reverse(LK(reverse(index))); keep it reversed.
    let shuffled_rev = laine_karras_permutation(index_rev, seed);
    scrambled_component(shuffled_rev, seed, (dim & 3) as usize)
}

/// Dimension groups whose scramble seeds [`SobolPixel`] computes once per pixel: the pixel plane
/// and the first five bounces (`dims`), which is nearly every sample value of a path that Russian
/// roulette ends.
const CACHED_GROUPS: usize = 16;

/// One pixel's scramble seeds: for each of the first [`CACHED_GROUPS`] dimension groups, the group
/// seed and the four component seeds. They depend on the pixel alone, not on the sample index, so
/// a pixel's samples share them: two hashes fewer per sample value (measured +3 % samples/s on the
/// Cornell box, docs/benchmarks.md). Deeper groups are hashed as they are drawn. The values are
/// exactly those of [`owen_sobol_sample`] and [`owen_sobol_pair`].
#[derive(Clone, Copy, Debug)]
pub struct SobolPixel {
    key: u32,
    group: [u32; CACHED_GROUPS],
    component: [[u32; 4]; CACHED_GROUPS],
}

impl SobolPixel {
    /// A placeholder for samplers that draw no Sobol values (its seeds are not the pixel's).
    pub const UNUSED: SobolPixel = SobolPixel {
        key: 0,
        group: [0; CACHED_GROUPS],
        component: [[0; 4]; CACHED_GROUPS],
    };

    pub fn new(pixel_key: u32) -> SobolPixel {
        let mut group = [0; CACHED_GROUPS];
        let mut component = [[0; 4]; CACHED_GROUPS];
        for (g, (seed, comps)) in group.iter_mut().zip(&mut component).enumerate() {
            *seed = group_seed(pixel_key, (g as u32) << 2);
            for (c, comp) in comps.iter_mut().enumerate() {
                *comp = component_seed(*seed, c);
            }
        }
        SobolPixel {
            key: pixel_key,
            group,
            component,
        }
    }

    /// The seeds of the group holding `dim`: the group's and its four components'.
    #[inline(always)]
    fn seeds(&self, dim: u32) -> (u32, [u32; 4]) {
        let g = (dim >> 2) as usize;
        match (self.group.get(g), self.component.get(g)) {
            (Some(&seed), Some(&comps)) => (seed, comps),
            _ => {
                let seed = group_seed(self.key, dim);
                (seed, [0, 1, 2, 3].map(|c| component_seed(seed, c)))
            }
        }
    }

    /// [`owen_sobol_sample`] of this pixel.
    #[inline(always)]
    pub fn sample(&self, index_rev: u32, dim: u32) -> f32 {
        let (seed, comps) = self.seeds(dim);
        let shuffled_rev = laine_karras_permutation(index_rev, seed);
        let c = (dim & 3) as usize;
        scrambled(shuffled_rev, comps[c], c)
    }

    /// [`owen_sobol_pair`] of this pixel.
    #[inline(always)]
    pub fn pair(&self, index_rev: u32, dim: u32) -> (f32, f32) {
        if dim & 3 == 3 {
            return (self.sample(index_rev, dim), self.sample(index_rev, dim + 1));
        }
        let (seed, comps) = self.seeds(dim);
        let shuffled_rev = laine_karras_permutation(index_rev, seed);
        let c = (dim & 3) as usize;
        (
            scrambled(shuffled_rev, comps[c], c),
            scrambled(shuffled_rev, comps[c + 1], c + 1),
        )
    }
}

/// [`owen_sobol_sample`] of dimensions `group + c` for each c of `components` (below four), where
/// `group` is the first dimension of a group (a multiple of four), in the form the wavefront
/// integrator's lanes are vectorised from: every seed hashed as it is drawn (lanes hold different
/// pixels and depths, so no per-pixel cache applies), the group's seed and index shuffle (half of
/// each value's multiplications) computed once for all its values, and the bit reversal by
/// `reverse_bits`, which compiles to SIMD shuffles, instead of byte tables, which would not
/// gather. The same bits (tested): the same hashes, and the reversal of the 24 bits that are kept.
#[inline(always)]
pub(crate) fn owen_sobol_group_lanewise<const N: usize>(
    pixel_key: u32,
    index_rev: u32,
    group: u32,
    components: [u32; N],
) -> [f32; N] {
    let seed = hash_u32(pixel_key ^ group_key(group >> 2));
    let shuffled_rev = laine_karras_permutation(index_rev, seed);
    // A loop, not `map` with a closure, which is not inlined into the vector steps' builds.
    let mut out = [0.0; N];
    for k in 0..N {
        let c = (components[k] & 3) as usize;
        let x_rev = sobol_reversed(shuffled_rev, c);
        out[k] =
            bits_to_unit(laine_karras_permutation(x_rev, component_seed(seed, c)).reverse_bits());
    }
    out
}

/// Dimensions `dim` and `dim + 1` at once (same values as two [`owen_sobol_sample`] calls, sharing
/// the index shuffle when both lie in one group of four).
#[inline(always)]
pub fn owen_sobol_pair(pixel_key: u32, index_rev: u32, dim: u32) -> (f32, f32) {
    if dim & 3 == 3 {
        return (
            owen_sobol_sample(pixel_key, index_rev, dim),
            owen_sobol_sample(pixel_key, index_rev, dim + 1),
        );
    }
    let seed = group_seed(pixel_key, dim);
    let shuffled_rev = laine_karras_permutation(index_rev, seed);
    let c = (dim & 3) as usize;
    (
        scrambled_component(shuffled_rev, seed, c),
        scrambled_component(shuffled_rev, seed, c + 1),
    )
}

/// The reference formulation (Burley 2020, listing 3), kept to test the fast path against.
#[cfg(test)]
fn owen_sobol_reference(pixel_key: u32, index: u32, dim: u32) -> f32 {
    let seed = group_seed(pixel_key, dim);
    let shuffled = nested_uniform_scramble(index, seed);
    let component = (dim & 3) as usize;
    let x = sobol(shuffled, component);
    bits_to_unit(nested_uniform_scramble(x, component_seed(seed, component)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_reversal_is_the_reversal_of_the_bits_that_are_kept() {
        let mut x = 0x9e37_79b9u32;
        for _ in 0..1_000_000 {
            x = hash_u32(x);
            assert_eq!(reverse_high24(x), x.reverse_bits() & !0xff, "{x:#x}");
            assert_eq!(
                bits_to_unit(reverse_high24(x)),
                bits_to_unit(x.reverse_bits())
            );
        }
    }

    #[test]
    fn first_dimensions_are_the_known_sobol_sequence() {
        // Unscrambled Sobol, dims 0 and 1, first 8 points (x 8), in index (not Gray-code) order.
        let d0: Vec<u32> = (0..8).map(|i| sobol(i, 0) >> 29).collect();
        let d1: Vec<u32> = (0..8).map(|i| sobol(i, 1) >> 29).collect();
        assert_eq!(d0, vec![0, 4, 2, 6, 1, 5, 3, 7]);
        assert_eq!(d1, vec![0, 4, 6, 2, 5, 1, 3, 7]);
    }

    #[test]
    fn byte_tables_match_the_bit_loop_and_pairs_match_singles() {
        for d in 0..4 {
            for i in [0u32, 1, 2, 3, 255, 256, 0xdead_beef, u32::MAX] {
                assert_eq!(
                    sobol_reversed(i.reverse_bits(), d),
                    sobol(i, d).reverse_bits()
                );
            }
        }
        for dim in 0..9 {
            for i in (0..50u32).chain([1 << 20, 0xdead_beef]) {
                let (a, b) = owen_sobol_pair(77, i.reverse_bits(), dim);
                assert_eq!(a, owen_sobol_sample(77, i.reverse_bits(), dim));
                assert_eq!(b, owen_sobol_sample(77, i.reverse_bits(), dim + 1));
                assert_eq!(
                    a,
                    owen_sobol_reference(77, i, dim),
                    "fast path differs from Burley's form"
                );
            }
        }
    }

    #[test]
    fn a_pixels_cached_seeds_give_the_values_of_the_hashed_ones() {
        for key in [0u32, 77, 0xdead_beef] {
            let pixel = SobolPixel::new(key);
            // Past the cached groups too, where the seeds are hashed as they are drawn.
            for dim in 0..(CACHED_GROUPS as u32 * 4 + 12) {
                for i in (0..40u32).chain([1 << 20, 0xdead_beef]) {
                    let r = i.reverse_bits();
                    assert_eq!(
                        pixel.sample(r, dim).to_bits(),
                        owen_sobol_sample(key, r, dim).to_bits()
                    );
                    let (a, b) = pixel.pair(r, dim);
                    let (c, d) = owen_sobol_pair(key, r, dim);
                    assert_eq!((a.to_bits(), b.to_bits()), (c.to_bits(), d.to_bits()));
                }
            }
        }
    }

    #[test]
    fn the_lanewise_form_gives_the_same_bits() {
        let mut key = 0x1234_5678u32;
        for dim in (0..80).chain([1020, 1023, 1024, 65_000, u32::MAX - 3]) {
            for i in (0..64u32).chain([1 << 20, 0xdead_beef, u32::MAX]) {
                key = hash_u32(key);
                let r = i.reverse_bits();
                let [one] = owen_sobol_group_lanewise(key, r, dim & !3, [dim & 3]);
                assert_eq!(
                    one.to_bits(),
                    owen_sobol_sample(key, r, dim).to_bits(),
                    "key {key:#x}, index {i}, dim {dim}"
                );
                let group = dim & !3;
                let [a, b, c, d] = owen_sobol_group_lanewise(key, r, group, [3, 0, 2, 1]);
                let want = [3, 0, 2, 1].map(|c| owen_sobol_sample(key, r, group + c).to_bits());
                assert_eq!(
                    [a, b, c, d].map(f32::to_bits),
                    want,
                    "key {key:#x}, index {i}"
                );
            }
        }
    }

    #[test]
    fn every_power_of_two_prefix_is_stratified_in_each_dimension() {
        for dim in 0..12u32 {
            for m in [4u32, 6, 8] {
                let n = 1u32 << m;
                let mut seen = vec![false; n as usize];
                for i in 0..n {
                    let u = owen_sobol_sample(0xdead_beef, i.reverse_bits(), dim);
                    let cell = (u * n as f32) as usize;
                    assert!(
                        !seen[cell],
                        "dim {dim}, n {n}: two points in stratum {cell}"
                    );
                    seen[cell] = true;
                }
            }
        }
    }

    #[test]
    fn pairs_zero_one_are_a_net() {
        // The first 256 points of dims (0,1) put exactly one point in each 16x16 elementary cell.
        let n = 256u32;
        let mut grid = vec![0u32; 256];
        for i in 0..n {
            let u = owen_sobol_sample(12345, i.reverse_bits(), 4);
            let v = owen_sobol_sample(12345, i.reverse_bits(), 5);
            grid[(u * 16.0) as usize * 16 + (v * 16.0) as usize] += 1;
        }
        assert!(grid.iter().all(|&c| c == 1));
    }
}
