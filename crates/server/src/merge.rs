//! The server's merge of accumulations: the tracer's exact merge, with every addition checked.
//!
//! The tracer adds with plain `+=`, which is right for what it renders itself (its samples are
//! bounded, see `pathfarm_tracer::accumulation`), but the server merges what clients uploaded. The
//! slice decoder refuses sums no honest sample set can reach, which keeps every merge far from the
//! `u128` range; this is the second line: an overflow is an error here, never a panic (which would
//! leave a tile that can never merge again) nor a silent wrap (which would break the exact merge).

use pathfarm_tracer::accumulation::MergeError;
use pathfarm_tracer::Accumulation;

/// Why a merge was refused. Nothing was changed.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum CheckedMergeError {
    #[error(transparent)]
    Shape(#[from] MergeError),
    #[error("the sums of pixel ({x}, {y}) would overflow")]
    Overflow { x: u32, y: u32 },
    #[error("the invalid sample count would overflow")]
    InvalidCount,
}

/// Adds `from` (which must lie inside `into`) into `into`, exactly as
/// [`Accumulation::merge`] does, after checking that no pixel sum or count and no invalid count
/// overflows; on an error `into` is unchanged. The ray count, a throughput statistic, saturates.
pub fn checked_merge(
    into: &mut Accumulation,
    from: &Accumulation,
) -> Result<(), CheckedMergeError> {
    let fits = from.x0 >= into.x0
        && from.y0 >= into.y0
        && from.x0 as u64 + from.width as u64 <= into.x0 as u64 + into.width as u64
        && from.y0 as u64 + from.height as u64 <= into.y0 as u64 + into.height as u64
        && from.pixels.len() as u64 == from.width as u64 * from.height as u64;
    if !fits {
        return Err(MergeError {
            got_x: from.x0,
            got_y: from.y0,
            got_w: from.width,
            got_h: from.height,
            x: into.x0,
            y: into.y0,
            w: into.width,
            h: into.height,
        }
        .into());
    }
    let (fw, iw) = (from.width as usize, into.width as usize);
    for row in 0..from.height as usize {
        let src = &from.pixels[row * fw..(row + 1) * fw];
        let start = (from.y0 - into.y0) as usize * iw + row * iw + (from.x0 - into.x0) as usize;
        for (i, (d, s)) in into.pixels[start..start + fw].iter().zip(src).enumerate() {
            let fits = d.count.checked_add(s.count).is_some()
                && d.sum_sq_lum.checked_add(s.sum_sq_lum).is_some()
                && (0..3).all(|c| d.sum[c].checked_add(s.sum[c]).is_some());
            if !fits {
                return Err(CheckedMergeError::Overflow {
                    x: from.x0 + i as u32,
                    y: from.y0 + row as u32,
                });
            }
        }
    }
    let invalid_count = into
        .invalid_count
        .checked_add(from.invalid_count)
        .ok_or(CheckedMergeError::InvalidCount)?;
    let rays = into.rays.saturating_add(from.rays);
    // The tracer's merge adds the pixels (checked above) and the invalid samples; with the two
    // counters zeroed it cannot overflow them, and they are set to the checked values after.
    let (old_rays, old_invalid) = (into.rays, into.invalid_count);
    into.rays = 0;
    into.invalid_count = 0;
    if let Err(e) = into.merge(from) {
        into.rays = old_rays;
        into.invalid_count = old_invalid;
        return Err(e.into());
    }
    into.rays = rays;
    into.invalid_count = invalid_count;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use pathfarm_tracer::accumulation::InvalidSample;

    fn acc(x0: u32, y0: u32, w: u32, h: u32, seed: u128) -> Accumulation {
        let mut a = Accumulation::new(x0, y0, w, h);
        for (i, p) in a.pixels.iter_mut().enumerate() {
            let v = seed * 1_000 + i as u128;
            p.sum = [v, 2 * v, 3 * v];
            p.sum_sq_lum = v * v;
            p.count = (seed as u64) + i as u64;
        }
        a.rays = 10 * seed as u64;
        a.invalid_count = seed as u64;
        a.invalid = vec![InvalidSample {
            x: x0,
            y: y0,
            index: seed as u32,
        }];
        a
    }

    #[test]
    fn merges_exactly_as_the_tracer_does() {
        let mut ours = acc(0, 0, 6, 5, 1);
        let mut theirs = ours.clone();
        for part in [acc(2, 1, 3, 2, 7), acc(0, 0, 6, 5, 3), acc(5, 4, 1, 1, 9)] {
            checked_merge(&mut ours, &part).unwrap();
            theirs.merge(&part).unwrap();
        }
        assert_eq!(ours, theirs);
    }

    #[test]
    fn an_overflow_is_an_error_and_changes_nothing() {
        let mut tile = acc(0, 0, 4, 4, 1);
        tile.pixels[5].sum[2] = u128::MAX - 1;
        let before = tile.clone();
        let slice = acc(0, 0, 4, 4, 2);
        assert_eq!(
            checked_merge(&mut tile, &slice),
            Err(CheckedMergeError::Overflow { x: 1, y: 1 })
        );
        assert_eq!(tile, before);
        let mut counted = acc(0, 0, 4, 4, 1);
        counted.invalid_count = u64::MAX;
        let before = counted.clone();
        assert_eq!(
            checked_merge(&mut counted, &slice),
            Err(CheckedMergeError::InvalidCount)
        );
        assert_eq!(counted, before);
        // Outside the target: the shape error, nothing changed.
        let mut small = acc(0, 0, 2, 2, 1);
        let before = small.clone();
        assert!(matches!(
            checked_merge(&mut small, &slice),
            Err(CheckedMergeError::Shape(_))
        ));
        assert_eq!(small, before);
    }

    #[test]
    fn rays_saturate() {
        let mut tile = acc(0, 0, 2, 2, 1);
        tile.rays = u64::MAX - 5;
        checked_merge(&mut tile, &acc(0, 0, 2, 2, 2)).unwrap();
        assert_eq!(tile.rays, u64::MAX);
    }
}
