//! Frame specifications of animation jobs: `1-240` (a range, both ends included), `1-240x2` (every
//! second frame of it), `1,5,10-12` (a list of either). Frames are non-negative integers; the
//! frames of a specification are kept in the order written, each once (a frame named twice is an
//! error, so that a job never renders one frame twice over).

use std::collections::BTreeSet;

/// The most frames one specification may name.
pub const MAX_FRAMES: usize = 10_000;
/// The largest frame number.
pub const MAX_FRAME: i64 = 10_000_000;
/// The most characters of a specification.
const MAX_SPEC_CHARS: usize = 4096;

/// Why a frame specification was refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameSpecError {
    #[error("frames is empty")]
    Empty,
    #[error("frames is longer than {MAX_SPEC_CHARS} characters")]
    TooLong,
    #[error("frames item {item:?}: {why}")]
    Item { item: String, why: String },
    #[error("frames names frame {0} more than once")]
    Repeated(i64),
    #[error("frames names more than {MAX_FRAMES} frames")]
    TooMany,
}

fn number(item: &str, s: &str) -> Result<i64, FrameSpecError> {
    let bad = |why: String| FrameSpecError::Item {
        item: item.to_string(),
        why,
    };
    if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
        return Err(bad(format!(
            "{s:?} is not a frame number (0 to {MAX_FRAME})"
        )));
    }
    match s.parse::<i64>() {
        Ok(n) if n <= MAX_FRAME => Ok(n),
        _ => Err(bad(format!("frame {s} is over {MAX_FRAME}"))),
    }
}

/// The frames of `spec`, in the order written.
pub fn parse_frames(spec: &str) -> Result<Vec<i64>, FrameSpecError> {
    if spec.chars().count() > MAX_SPEC_CHARS {
        return Err(FrameSpecError::TooLong);
    }
    let spec = spec.trim();
    if spec.is_empty() {
        return Err(FrameSpecError::Empty);
    }
    let mut frames = Vec::new();
    let mut seen = BTreeSet::new();
    for raw in spec.split(',') {
        let item = raw.trim();
        let bad = |why: &str| FrameSpecError::Item {
            item: item.to_string(),
            why: why.to_string(),
        };
        if item.is_empty() {
            return Err(bad("an empty item"));
        }
        let (range, step) = match item.split_once('x') {
            Some((r, s)) => (r.trim(), Some(number(item, s.trim())?)),
            None => (item, None),
        };
        let (first, last) = match range.split_once('-') {
            Some((a, b)) => (number(item, a.trim())?, number(item, b.trim())?),
            None if step.is_some() => return Err(bad("a step needs a range (`1-240x2`)")),
            None => {
                let n = number(item, range)?;
                (n, n)
            }
        };
        if last < first {
            return Err(bad("the range ends before it starts"));
        }
        let step = step.unwrap_or(1);
        if step == 0 {
            return Err(bad("the step must be at least 1"));
        }
        // Counted before anything is allocated: a range of ten million frames is refused here.
        let count = (last - first) / step + 1;
        if frames.len() as i64 + count > MAX_FRAMES as i64 {
            return Err(FrameSpecError::TooMany);
        }
        let mut f = first;
        while f <= last {
            if !seen.insert(f) {
                return Err(FrameSpecError::Repeated(f));
            }
            frames.push(f);
            f += step;
        }
    }
    Ok(frames)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_steps_and_lists() {
        assert_eq!(parse_frames("7").unwrap(), [7]);
        assert_eq!(parse_frames("1-4").unwrap(), [1, 2, 3, 4]);
        assert_eq!(parse_frames("1-9x3").unwrap(), [1, 4, 7]);
        assert_eq!(parse_frames("1-10x3").unwrap(), [1, 4, 7, 10]);
        assert_eq!(
            parse_frames(" 1, 5 ,10-12, 20-24x2").unwrap(),
            [1, 5, 10, 11, 12, 20, 22, 24]
        );
        assert_eq!(parse_frames("3,1,2").unwrap(), [3, 1, 2]);
        assert_eq!(parse_frames("0-0").unwrap(), [0]);
        assert_eq!(parse_frames("1-240").unwrap().len(), 240);
        assert_eq!(parse_frames("1-240x2").unwrap().len(), 120);
        assert_eq!(
            parse_frames(&format!("0-{}", MAX_FRAMES - 1))
                .unwrap()
                .len(),
            MAX_FRAMES
        );
    }

    #[test]
    fn bad_specifications_are_errors_naming_the_item() {
        for (spec, want) in [
            ("", "empty"),
            ("  ", "empty"),
            ("1,,2", "an empty item"),
            ("a", "not a frame number"),
            ("-3", "not a frame number"),
            ("1--3", "not a frame number"),
            ("5-1", "ends before it starts"),
            ("1-9x0", "at least 1"),
            ("4x2", "needs a range"),
            ("1-9x", "not a frame number"),
            ("1.5", "not a frame number"),
            ("+3", "not a frame number"),
            ("99999999999999999999999", "over"),
            ("20000000", "over"),
            ("1-3,2", "more than once"),
            ("0-10000", "more than 10000 frames"),
            ("0-10000000", "more than 10000 frames"),
            ("1-2x3x4", "not a frame number"),
        ] {
            let e = parse_frames(spec).expect_err(spec).to_string();
            assert!(e.contains(want), "{spec:?}: {e}");
            assert!(e.starts_with("frames"), "{spec:?}: {e}");
        }
        assert_eq!(
            parse_frames(&"1,".repeat(3000)),
            Err(FrameSpecError::TooLong)
        );
    }

    /// Arbitrary strings over the specification's alphabet never panic.
    #[test]
    fn arbitrary_input_never_panics() {
        let alphabet: Vec<char> = "0123456789-x, 9é\u{0}".chars().collect();
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        for _ in 0..50_000 {
            let mut s = String::new();
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let len = (state % 12) as usize;
            for i in 0..len {
                let r = state.rotate_left(5 * i as u32);
                s.push(alphabet[(r % alphabet.len() as u64) as usize]);
            }
            if let Ok(frames) = parse_frames(&s) {
                assert!(!frames.is_empty() && frames.len() <= MAX_FRAMES, "{s:?}");
                assert!(frames.iter().all(|f| (0..=MAX_FRAME).contains(f)), "{s:?}");
            }
        }
    }
}
