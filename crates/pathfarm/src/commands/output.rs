//! Image output files (`render --out`, `submit --out`, `job --out`): checked before any work
//! starts, so that a render or a job never runs only for its image to be refused.

use anyhow::{bail, Context, Result};
use std::path::Path;

/// What `--out` asks for, from its extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutFormat {
    Exr,
    Png,
}

/// The format `out`'s extension names.
pub fn out_format(out: &Path) -> Result<OutFormat> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("png") => Ok(OutFormat::Png),
        Some("exr") => Ok(OutFormat::Exr),
        _ => bail!("--out must end in .exr or .png (got {})", out.display()),
    }
}

/// The file of frame `frame` in a frame job's `--out` pattern: its last run of `#` replaced by
/// the frame number, padded with zeros to the run's length (`shots/frame_####.exr`, frame 7:
/// `shots/frame_0007.exr`; a longer number is written whole). `None` when the file name has no
/// `#`.
pub fn frame_path(pattern: &Path, frame: i64) -> Option<std::path::PathBuf> {
    let name = pattern.file_name()?.to_str()?;
    let end = name.rfind('#')? + 1;
    let start = name[..end].trim_end_matches('#').len();
    let width = end - start;
    let file = format!("{}{frame:0width$}{}", &name[..start], &name[end..]);
    Some(pattern.with_file_name(file))
}

/// Checks `--out` before the work: a known extension, a folder that exists and can be written
/// in (a probe file is created there and removed), and not a folder itself. Images are written
/// to a temporary file in the same folder and renamed, so this is what writing will need.
pub fn check_output(out: &Path) -> Result<OutFormat> {
    let format = out_format(out)?;
    check_folder(out)?;
    Ok(format)
}

/// A frame job's frames in one file (`job --out`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Archive {
    /// `.tar`: every frame with a sample, as EXRs.
    Tar,
    /// `.apng`: the complete frames as an animated PNG.
    Apng,
}

/// The archive `out`'s extension names, checked as [`check_output`] checks an image; `None`
/// when it names none (an image, then).
pub fn check_archive(out: &Path) -> Result<Option<Archive>> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let archive = match ext.as_deref() {
        Some("tar") => Archive::Tar,
        Some("apng") => Archive::Apng,
        _ => return Ok(None),
    };
    check_folder(out)?;
    Ok(Some(archive))
}

fn check_folder(out: &Path) -> Result<()> {
    let dir = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => {}
        Ok(_) => bail!("--out {}: {} is not a folder", out.display(), dir.display()),
        Err(e) => bail!(
            "--out {}: the folder {} cannot be used: {e}",
            out.display(),
            dir.display()
        ),
    }
    if out.is_dir() {
        bail!("--out {} is a folder, not a file", out.display());
    }
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let probe = dir.join(format!(".{name}.pathfarm-probe-{}", std::process::id()));
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .with_context(|| format!("--out {}: cannot write in {}", out.display(), dir.display()))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_paths_fill_the_last_run_of_hashes() {
        let p = |s: &str, f| frame_path(Path::new(s), f).map(|p| p.display().to_string());
        assert_eq!(
            p("shots/frame_####.exr", 7).as_deref(),
            Some("shots/frame_0007.exr")
        );
        assert_eq!(p("f#.png", 1234).as_deref(), Some("f1234.png"));
        assert_eq!(p("a##_b###.exr", 12).as_deref(), Some("a##_b012.exr"));
        assert_eq!(p("x.exr", 1), None);
        assert_eq!(p("dir#/x.exr", 1), None);
    }

    #[test]
    fn out_format_is_known_from_the_extension() {
        assert_eq!(out_format(Path::new("a/b.PNG")).unwrap(), OutFormat::Png);
        assert_eq!(out_format(Path::new("b.exr")).unwrap(), OutFormat::Exr);
        for bad in ["b.jpg", "b", "exr", "dir/.png.txt"] {
            let e = out_format(Path::new(bad)).unwrap_err().to_string();
            assert!(e.contains("--out must end in .exr or .png"), "{bad}: {e}");
        }
    }

    #[test]
    fn a_missing_or_unusable_folder_is_refused_naming_it() {
        let base = std::env::temp_dir().join(format!("pathfarm-out-{}", std::process::id()));
        std::fs::create_dir_all(&base).unwrap();
        let e = check_output(&base.join("missing/x.exr"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing") && e.contains("cannot be used"), "{e}");
        std::fs::write(base.join("file"), b"").unwrap();
        let e = check_output(&base.join("file/x.png"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("is not a folder"), "{e}");
        std::fs::create_dir_all(base.join("d.exr")).unwrap();
        let e = check_output(&base.join("d.exr")).unwrap_err().to_string();
        assert!(e.contains("is a folder"), "{e}");
        assert_eq!(check_output(&base.join("ok.exr")).unwrap(), OutFormat::Exr);
        // The probe is gone.
        let left: Vec<_> = std::fs::read_dir(&base)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(left.len(), 2, "{left:?}");
        let _ = std::fs::remove_dir_all(&base);
    }
}
