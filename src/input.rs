//! Reading the files a command is handed (specs, scenario and intervention
//! files, a dataset's records and logs): regular files only, and records
//! within a size fit for what they hold, so that a pipe never hangs a
//! command and a device (`/dev/zero`, a link to it) never fills memory.
//! Errors are `io::Error`s, so callers name the file as they name any
//! other read error. Imports nothing from the crate.

use std::io::{self, Read};
use std::path::Path;

/// Largest JSON record read whole, bytes: a spec, a scenario or
/// intervention file, `manifest.json`, `sweep.json`, a scenario's
/// `scenario.json` or a pair's `summary.json`. The largest written today
/// are a few MB (a manifest's spec with its groups; a 96-car scenario.json).
pub const MAX_RECORD_BYTES: u64 = 256 << 20;

/// The bytes of the regular file at `path` (followed through links), at
/// most `limit` of them; an error for a pipe, a device, a folder or a
/// larger file.
pub fn read_regular(path: &Path, limit: u64) -> io::Result<Vec<u8>> {
    let metadata = regular_file(path)?;
    let too_large = |size: u64| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!("{size} bytes, more than the {limit} this file can hold; it is not read"),
        )
    };
    if metadata.len() > limit {
        return Err(too_large(metadata.len()));
    }
    // A file larger than memory (a sparse one, say) is an error, not an
    // abort.
    let mut bytes = Vec::new();
    bytes.try_reserve_exact(metadata.len() as usize).map_err(|_| {
        io::Error::new(io::ErrorKind::OutOfMemory, format!("{} bytes, more than memory holds", metadata.len()))
    })?;
    // (A file that grows while read stops at the limit.)
    std::fs::File::open(path)?.take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

/// The metadata of the regular file at `path` (followed through links); an
/// error for a pipe, a device or a folder, which readers never open.
pub fn regular_file(path: &Path) -> io::Result<std::fs::Metadata> {
    let metadata = std::fs::metadata(path)?;
    if metadata.is_file() {
        return Ok(metadata);
    }
    let what = if metadata.is_dir() { "a folder" } else { "not a regular file (a pipe or a device)" };
    Err(io::Error::new(io::ErrorKind::InvalidInput, format!("{what}, so it is not read")))
}

/// [`read_regular`] of a JSON record (at most [`MAX_RECORD_BYTES`]).
pub fn read_record(path: &Path) -> io::Result<Vec<u8>> {
    read_regular(path, MAX_RECORD_BYTES)
}

/// [`read_record`] as UTF-8 text.
pub fn read_record_text(path: &Path) -> io::Result<String> {
    String::from_utf8(read_record(path)?)
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidData, "stream did not contain valid UTF-8"))
}

/// [`read_regular`] of a data file (a log or an array): any size.
pub fn read_data(path: &Path) -> io::Result<Vec<u8>> {
    read_regular(path, u64::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pipes_devices_folders_and_oversized_records_are_refused_by_what_they_are() {
        let said = |r: io::Result<Vec<u8>>| r.unwrap_err().to_string();
        assert!(said(read_record(Path::new("/dev/zero"))).contains("not a regular file"));
        assert!(said(read_record(Path::new("/"))).contains("a folder"));
        let dir = std::env::temp_dir().join(format!("causalcity-input-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("record.json");
        std::fs::write(&file, b"{\"a\": 1}").unwrap();
        assert_eq!(read_record(&file).unwrap(), b"{\"a\": 1}");
        assert!(said(read_regular(&file, 3)).contains("8 bytes, more than the 3"));
        std::fs::write(&file, [0xff, 0xfe]).unwrap();
        assert!(read_record_text(&file).unwrap_err().to_string().contains("UTF-8"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
