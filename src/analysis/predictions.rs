//! A predictions file as numpy writes it (`np.savez` or `np.savez_compressed`:
//! a zip of `.npy` arrays), read into named arrays of f64 for `evaluate`.
//! Any real or integer dtype (float16 included) or bool, of either byte
//! order, is accepted, in C or Fortran order (a transposed array is saved
//! in Fortran order); the values come back in C order.
//!
//! The file is untrusted: no size it declares (a zip entry's, an `.npy`
//! header's length or shape) is believed. The caller says how many values
//! each array name may hold (the scenario's cars and frames set that), each
//! entry is read through a cap of that many bytes, memory is reserved
//! fallibly, and every count is checked arithmetic. A file that asks for
//! more is refused, naming the entry.

use std::collections::HashSet;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

/// One array of a predictions file.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedArray {
    /// Its name in the archive (the `.npy` file's name without `.npy`).
    pub name: String,
    pub shape: Vec<usize>,
    /// Row-major (C order) values.
    pub values: Vec<f64>,
}

/// The longest `.npy` header accepted, bytes (numpy writes at most a few
/// hundred; its own reader refuses more than 10,000 by default).
pub const MAX_NPY_HEADER: u64 = 64 * 1024;

/// The widest dtype accepted, bytes per value (float64, int64, uint64).
const MAX_ITEM_SIZE: u64 = 8;

/// Reads every array of the `.npz` at `path`, in archive order.
/// `max_values(name)` gives how many values the array `name` may hold, or
/// an error for a name that has no place in the file. Errors name the file
/// and, where one is at fault, the array.
pub fn read_npz(path: &Path, max_values: impl FnMut(&str) -> Result<u64, String>) -> Result<Vec<NamedArray>, String> {
    let cannot = |e: std::io::Error| format!("cannot read {}: {e}", path.display());
    crate::input::regular_file(path).map_err(cannot)?;
    let file = std::fs::File::open(path).map_err(cannot)?;
    read_npz_from(std::io::BufReader::new(file), max_values).map_err(|e| format!("{}: {e}", path.display()))
}

/// [`read_npz`] over any reader (errors without the file's name).
pub fn read_npz_from(
    mut reader: impl Read + Seek,
    mut max_values: impl FnMut(&str) -> Result<u64, String>,
) -> Result<Vec<NamedArray>, String> {
    // The zip reader keeps one entry per name (the last): duplicates are
    // found in the central directory itself.
    if let Some(name) = duplicate_name(&mut reader)? {
        return Err(twice(name.strip_suffix(".npy").unwrap_or(&name)));
    }
    reader.seek(SeekFrom::Start(0)).map_err(|e| format!("cannot be read: {e}"))?;
    let mut archive =
        zip::ZipArchive::new(reader).map_err(|e| format!("not an .npz file (numpy's np.savez writes one): {e}"))?;
    let mut arrays = Vec::new();
    for index in 0..archive.len() {
        let entry = archive.by_index(index).map_err(|e| format!("entry {index}: {e}"))?;
        if entry.is_dir() {
            continue;
        }
        let entry_name = entry.name().to_string();
        let Some(name) = entry_name.strip_suffix(".npy").map(str::to_string) else {
            return Err(format!("holds {entry_name:?}, which is no .npy array"));
        };
        let allowed = max_values(&name)?;
        let cap = allowed.checked_mul(MAX_ITEM_SIZE).and_then(|b| b.checked_add(MAX_NPY_HEADER)).unwrap_or(u64::MAX);
        // A declared size is only ever a reason to refuse early, never to
        // reserve memory: the read below is capped whatever it says.
        if entry.size() > cap {
            return Err(format!(
                "array {name:?} declares {} bytes, more than any array of its kind can be here (at most \
                 {allowed} values, {cap} bytes with its header); refused without reading it",
                entry.size()
            ));
        }
        let bytes = read_capped(entry, cap).map_err(|e| format!("array {name:?}: {e}"))?;
        let Some(bytes) = bytes else {
            return Err(format!(
                "array {name:?} holds more than any array of its kind can be here (at most {allowed} values, \
                 {cap} bytes with its header); refused without reading further"
            ));
        };
        let array = parse_npy(name, &bytes, allowed)?;
        arrays.push(array);
    }
    Ok(arrays)
}

/// The one array `name` of the `.npz` file at `path`, read alone (at most
/// `max_values` values), if the file holds it; `None` too where the file
/// is no readable zip: [`read_npz`] then says why.
pub fn read_npz_array(path: &Path, name: &str, max_values: u64) -> Result<Option<NamedArray>, String> {
    let Ok(_) = crate::input::regular_file(path) else { return Ok(None) };
    let Ok(file) = std::fs::File::open(path) else { return Ok(None) };
    let Ok(mut archive) = zip::ZipArchive::new(std::io::BufReader::new(file)) else { return Ok(None) };
    let Ok(entry) = archive.by_name(&format!("{name}.npy")) else { return Ok(None) };
    let cap = max_values.checked_mul(MAX_ITEM_SIZE).and_then(|b| b.checked_add(MAX_NPY_HEADER)).unwrap_or(u64::MAX);
    let tell = |e: String| format!("{}: array {name:?}: {e}", path.display());
    let bytes =
        read_capped(entry, cap).map_err(tell)?.ok_or_else(|| tell(format!("holds more than {max_values} values")))?;
    parse_npy(name.to_string(), &bytes, max_values).map(Some).map_err(|e| format!("{}: {e}", path.display()))
}

fn twice(name: &str) -> String {
    format!(
        "holds the array {name:?} twice: each array name may appear once (np.savez never writes a name twice; \
         the file was put together by other means)"
    )
}

/// The longest central directory read to look for duplicate names: 64 MiB
/// lists about half a million arrays.
const MAX_CENTRAL_DIRECTORY: u64 = 64 << 20;

/// A little-endian field of `width` bytes at `at`, if `bytes` hold it.
fn field(bytes: &[u8], at: usize, width: usize) -> Option<u64> {
    let raw = bytes.get(at..at.checked_add(width)?)?;
    Some(raw.iter().rev().fold(0u64, |v, &b| (v << 8) | b as u64))
}

/// The first entry name the zip's central directory lists twice. A file
/// whose directory cannot be found here is left to the zip reader to refuse.
fn duplicate_name(reader: &mut (impl Read + Seek)) -> Result<Option<String>, String> {
    let io = |e: std::io::Error| format!("cannot be read: {e}");
    let len = reader.seek(SeekFrom::End(0)).map_err(io)?;
    // The end record (22 bytes) and a comment of at most 65,535.
    let tail_len = len.min(22 + 65_535);
    reader.seek(SeekFrom::Start(len - tail_len)).map_err(io)?;
    let mut tail = vec![0u8; tail_len as usize];
    reader.read_exact(&mut tail).map_err(io)?;
    let Some(end) = tail.windows(4).rposition(|w| w == b"PK\x05\x06") else { return Ok(None) };
    let (Some(mut entries), Some(mut size), Some(mut offset)) =
        (field(&tail, end + 10, 2), field(&tail, end + 12, 4), field(&tail, end + 16, 4))
    else {
        return Ok(None);
    };
    // Zip64: a locator just before the end record points at the zip64 end record.
    let zip64 = entries == 0xffff || size == 0xffff_ffff || offset == 0xffff_ffff;
    if zip64 && end >= 20 && tail[end - 20..].starts_with(b"PK\x06\x07") {
        let Some(at) = field(&tail, end - 20 + 8, 8).filter(|at| at.checked_add(56).is_some_and(|e| e <= len)) else {
            return Ok(None);
        };
        reader.seek(SeekFrom::Start(at)).map_err(io)?;
        let mut record = [0u8; 56];
        reader.read_exact(&mut record).map_err(io)?;
        match (record.starts_with(b"PK\x06\x06"), field(&record, 32, 8), field(&record, 40, 8), field(&record, 48, 8)) {
            (true, Some(e), Some(s), Some(o)) => (entries, size, offset) = (e, s, o),
            _ => return Ok(None),
        }
    }
    if size > MAX_CENTRAL_DIRECTORY || offset.checked_add(size).is_none_or(|e| e > len) {
        return Ok(None);
    }
    reader.seek(SeekFrom::Start(offset)).map_err(io)?;
    let mut directory = vec![0u8; size as usize];
    reader.read_exact(&mut directory).map_err(io)?;
    let mut names = HashSet::new();
    let mut at = 0usize;
    for _ in 0..entries {
        if directory.get(at..at + 4) != Some(b"PK\x01\x02".as_slice()) {
            break;
        }
        let (Some(name_len), Some(extra_len), Some(comment_len)) =
            (field(&directory, at + 28, 2), field(&directory, at + 30, 2), field(&directory, at + 32, 2))
        else {
            break;
        };
        let Some(name) = directory.get(at + 46..at + 46 + name_len as usize) else { break };
        let name = String::from_utf8_lossy(name).into_owned();
        if !names.insert(name.clone()) {
            return Ok(Some(name));
        }
        at += 46 + (name_len + extra_len + comment_len) as usize;
    }
    Ok(None)
}

/// Up to `cap` bytes of `entry`, or None when it holds more. Memory grows
/// with what is actually read, never with what the entry declares.
fn read_capped(entry: impl Read, cap: u64) -> Result<Option<Vec<u8>>, String> {
    let mut bytes = Vec::new();
    let mut limited = entry.take(cap.saturating_add(1));
    let mut chunk = [0u8; 64 * 1024];
    loop {
        let n = match limited.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(format!("cannot be read: {e}")),
        };
        bytes.try_reserve(n).map_err(|_| format!("does not fit in memory ({} bytes read so far)", bytes.len()))?;
        bytes.extend_from_slice(&chunk[..n]);
        if bytes.len() as u64 > cap {
            return Ok(None);
        }
    }
    Ok(Some(bytes))
}

/// The parts of an `.npy` header `evaluate` uses.
#[derive(Debug, PartialEq)]
struct NpyHeader {
    descr: String,
    fortran_order: bool,
    shape: Vec<u64>,
}

/// One `.npy` file's bytes as a [`NamedArray`] of at most `allowed` values.
fn parse_npy(name: String, bytes: &[u8], allowed: u64) -> Result<NamedArray, String> {
    let bad = |what: &dyn std::fmt::Display| format!("array {name:?}: {what}");
    let (header, data) = split_npy(bytes).map_err(|e| bad(&format!("is not a valid .npy array ({e})")))?;
    let header = parse_header(header).map_err(|e| bad(&format!("has an unreadable .npy header ({e})")))?;
    let dtype = Dtype::parse(&header.descr).map_err(|e| bad(&e))?;
    let count = header.shape.iter().try_fold(1u64, |n, &d| n.checked_mul(d));
    let Some(count) = count.filter(|&n| n <= allowed) else {
        return Err(bad(&format!(
            "declares shape {:?}, more than the {allowed} values any array of its kind can hold here",
            header.shape
        )));
    };
    // count <= allowed, whose bytes were capped above: these fit.
    let needed = count * dtype.size as u64;
    if (data.len() as u64) < needed {
        return Err(bad(&format!(
            "is truncated: its shape {:?} of {} needs {needed} bytes of data, and the file holds {}",
            header.shape,
            header.descr,
            data.len()
        )));
    }
    let mut values = Vec::new();
    values.try_reserve_exact(count as usize).map_err(|_| bad(&format!("{count} values do not fit in memory")))?;
    values.extend(data[..needed as usize].chunks_exact(dtype.size).map(|item| dtype.value(item)));
    let shape: Vec<usize> = header.shape.iter().map(|&d| d as usize).collect();
    let values = if header.fortran_order { fortran_to_c(&values, &shape) } else { values };
    Ok(NamedArray { name, shape, values })
}

/// An `.npy` file's header text and its data.
fn split_npy(bytes: &[u8]) -> Result<(&str, &[u8]), String> {
    let rest = bytes.strip_prefix(b"\x93NUMPY").ok_or("no \\x93NUMPY magic")?;
    let Some((&[major, _minor], rest)) = rest.split_first_chunk::<2>() else {
        return Err("cut short".into());
    };
    let (length, rest) = match major {
        1 => rest.split_first_chunk::<2>().map(|(n, r)| (u16::from_le_bytes(*n) as u64, r)),
        2 | 3 => rest.split_first_chunk::<4>().map(|(n, r)| (u32::from_le_bytes(*n) as u64, r)),
        v => return Err(format!("format version {v}, where numpy writes 1, 2 or 3")),
    }
    .ok_or("cut short")?;
    if length > MAX_NPY_HEADER {
        return Err(format!("a header of {length} bytes, more than the {MAX_NPY_HEADER} accepted"));
    }
    if length > rest.len() as u64 {
        return Err(format!("a header of {length} bytes, but only {} follow", rest.len()));
    }
    let (header, data) = rest.split_at(length as usize);
    let header = std::str::from_utf8(header).map_err(|_| "a header that is not text".to_string())?;
    Ok((header, data))
}

/// Parses numpy's header, a Python dict literal such as `{'descr': '<f8',
/// 'fortran_order': False, 'shape': (3, 4), }`.
fn parse_header(text: &str) -> Result<NpyHeader, String> {
    let mut p = Literal { text: text.trim_end_matches(['\n', ' ', '\0']), at: 0 };
    p.expect('{')?;
    let (mut descr, mut fortran_order, mut shape) = (None, None, None);
    loop {
        p.skip_space();
        if p.eat('}') {
            break;
        }
        let key = p.string()?;
        p.expect(':')?;
        p.skip_space();
        match key.as_str() {
            "descr" if p.peek() == Some('[') => {
                return Err("a structured dtype (a list of fields); give plain numbers".into());
            }
            "descr" => descr = Some(p.string()?),
            "fortran_order" => fortran_order = Some(p.boolean()?),
            "shape" => shape = Some(p.shape()?),
            other => return Err(format!("an unknown key {other:?}")),
        }
        p.skip_space();
        if !p.eat(',') {
            p.expect('}')?;
            break;
        }
    }
    p.skip_space();
    if p.at != p.text.len() {
        return Err("text after the dict".into());
    }
    Ok(NpyHeader {
        descr: descr.ok_or("no 'descr'")?,
        fortran_order: fortran_order.ok_or("no 'fortran_order'")?,
        shape: shape.ok_or("no 'shape'")?,
    })
}

/// A cursor over a Python literal.
struct Literal<'a> {
    text: &'a str,
    at: usize,
}

impl Literal<'_> {
    fn peek(&self) -> Option<char> {
        self.text[self.at..].chars().next()
    }

    fn skip_space(&mut self) {
        while self.peek().is_some_and(|c| c.is_ascii_whitespace()) {
            self.at += 1;
        }
    }

    fn eat(&mut self, c: char) -> bool {
        if self.peek() == Some(c) {
            self.at += c.len_utf8();
            true
        } else {
            false
        }
    }

    fn expect(&mut self, c: char) -> Result<(), String> {
        self.skip_space();
        if self.eat(c) {
            Ok(())
        } else {
            Err(format!("expected {c:?} at byte {}", self.at))
        }
    }

    fn string(&mut self) -> Result<String, String> {
        self.skip_space();
        let quote = self.peek().filter(|q| *q == '\'' || *q == '"').ok_or("expected a quoted string")?;
        self.at += 1;
        let rest = &self.text[self.at..];
        let end = rest.find(quote).ok_or("an unterminated string")?;
        self.at += end + 1;
        Ok(rest[..end].to_string())
    }

    fn boolean(&mut self) -> Result<bool, String> {
        for (word, value) in [("True", true), ("False", false)] {
            if self.text[self.at..].starts_with(word) {
                self.at += word.len();
                return Ok(value);
            }
        }
        Err("expected True or False".into())
    }

    /// A tuple of whole numbers: `()`, `(3,)`, `(3, 4)`.
    fn shape(&mut self) -> Result<Vec<u64>, String> {
        self.expect('(')?;
        let mut dims = Vec::new();
        loop {
            self.skip_space();
            if self.eat(')') {
                return Ok(dims);
            }
            let digits = self.text[self.at..].chars().take_while(char::is_ascii_digit).count();
            if digits == 0 {
                return Err("a shape that is not a tuple of whole numbers".into());
            }
            let dim = self.text[self.at..self.at + digits].parse::<u64>().map_err(|_| "a dimension too large")?;
            self.at += digits;
            dims.push(dim);
            // A stray 'L' (Python 2's long) is accepted, as numpy does.
            self.eat('L');
            self.skip_space();
            if !self.eat(',') {
                self.expect(')')?;
                return Ok(dims);
            }
        }
    }
}

/// A plain numeric dtype: how to turn one item's bytes into an f64.
#[derive(Debug, Clone, Copy)]
struct Dtype {
    kind: char,
    size: usize,
    big_endian: bool,
}

impl Dtype {
    fn parse(descr: &str) -> Result<Dtype, String> {
        let refuse = || format!("has dtype {descr:?}; give floats (float16/32/64), integers or bools");
        let mut chars = descr.chars();
        let order = chars.next().ok_or_else(refuse)?;
        let (big_endian, rest) = match order {
            '<' | '|' | '=' => (false, chars.as_str()),
            '>' => (true, chars.as_str()),
            _ => (false, descr),
        };
        let mut chars = rest.chars();
        let kind = chars.next().ok_or_else(refuse)?;
        let size: usize = chars.as_str().parse().map_err(|_| refuse())?;
        let fits = match kind {
            'f' => matches!(size, 2 | 4 | 8),
            'i' | 'u' => matches!(size, 1 | 2 | 4 | 8),
            'b' => size == 1,
            _ => false,
        };
        if fits {
            Ok(Dtype { kind, size, big_endian })
        } else {
            Err(refuse())
        }
    }

    fn value(self, item: &[u8]) -> f64 {
        let mut raw = [0u8; 8];
        raw[..self.size].copy_from_slice(item);
        if self.big_endian {
            raw[..self.size].reverse();
        }
        let bits = u64::from_le_bytes(raw);
        let signed = |width: u32| ((bits << (64 - width)) as i64 >> (64 - width)) as f64;
        match (self.kind, self.size) {
            ('f', 2) => f16_to_f64(bits as u16),
            ('f', 4) => f32::from_bits(bits as u32) as f64,
            ('f', _) => f64::from_bits(bits),
            ('i', n) => signed(8 * n as u32),
            ('b', _) => (bits != 0) as u8 as f64,
            (_, _) => bits as f64,
        }
    }
}

/// An IEEE 754 half-precision value, exactly.
fn f16_to_f64(bits: u16) -> f64 {
    let sign = if bits & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exponent = i32::from((bits >> 10) & 0x1f);
    let fraction = f64::from(bits & 0x3ff);
    sign * match exponent {
        0 => fraction * 2f64.powi(-24),
        31 if fraction == 0.0 => f64::INFINITY,
        31 => f64::NAN,
        e => (1.0 + fraction / 1024.0) * 2f64.powi(e - 15),
    }
}

/// Reorders values stored first-axis-fastest (Fortran) into row-major order.
fn fortran_to_c(values: &[f64], shape: &[usize]) -> Vec<f64> {
    let mut out = vec![0.0; values.len()];
    let mut index = vec![0usize; shape.len()];
    for value in values {
        // `index` walks the Fortran order; its row-major offset is where `value` goes.
        let offset = index.iter().zip(shape).fold(0, |offset, (&i, &n)| offset * n + i);
        out[offset] = *value;
        for (i, &n) in index.iter_mut().zip(shape) {
            *i += 1;
            if *i < n {
                break;
            }
            *i = 0;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fortran_order_comes_back_row_major() {
        // [[1, 2, 3], [4, 5, 6]] stored column by column.
        assert_eq!(fortran_to_c(&[1.0, 4.0, 2.0, 5.0, 3.0, 6.0], &[2, 3]), vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        // A [2, 2, 2] block: element (i, j, k) holds 100 i + 10 j + k.
        let c: Vec<f64> = (0..8).map(|n| (100 * (n / 4) + 10 * (n / 2 % 2) + n % 2) as f64).collect();
        let f: Vec<f64> = (0..8).map(|n| (100 * (n % 2) + 10 * (n / 2 % 2) + n / 4) as f64).collect();
        assert_eq!(fortran_to_c(&f, &[2, 2, 2]), c);
    }

    #[test]
    fn numpy_headers_parse() {
        let h = parse_header("{'descr': '<f8', 'fortran_order': False, 'shape': (3, 4), }").unwrap();
        assert_eq!(h, NpyHeader { descr: "<f8".into(), fortran_order: false, shape: vec![3, 4] });
        let h = parse_header("{'descr': '|b1', 'fortran_order': True, 'shape': (5,), }    \n").unwrap();
        assert_eq!((h.fortran_order, h.shape), (true, vec![5]));
        assert_eq!(
            parse_header("{'descr': '<f4', 'fortran_order': False, 'shape': ()}").unwrap().shape,
            Vec::<u64>::new()
        );
        assert!(parse_header("{'descr': [('a', '<f8')], 'fortran_order': False, 'shape': (1,)}")
            .unwrap_err()
            .contains("structured"));
        assert!(parse_header("{'descr': '<f8', 'shape': (1,)}").unwrap_err().contains("fortran_order"));
        assert!(parse_header("{'descr': '<f8', 'fortran_order': False, 'shape': (99999999999999999999,)}").is_err());
        // Whitespace beyond ASCII (a no-break or ideographic space) is not
        // Python's: an error, never a panic (it stepped into the middle of
        // the character).
        for odd in ["{\u{a0}'descr': '<f8', 'fortran_order': False, 'shape': (4, 4), }", "{'descr':\u{3000}'<f8'}"] {
            assert!(parse_header(odd).is_err(), "{odd}");
        }
    }

    #[test]
    fn every_plain_dtype_decodes() {
        let v = |descr: &str, bytes: &[u8]| Dtype::parse(descr).unwrap().value(bytes);
        assert_eq!(v("<f2", &0x3c00u16.to_le_bytes()), 1.0);
        assert_eq!(v("<f2", &0xc100u16.to_le_bytes()), -2.5);
        assert_eq!(v("<f2", &0x0001u16.to_le_bytes()), 2f64.powi(-24));
        assert!(v("<f2", &0x7c00u16.to_le_bytes()).is_infinite());
        assert_eq!(v(">f4", &1.5f32.to_be_bytes()), 1.5);
        assert_eq!(v("<f8", &(-0.25f64).to_le_bytes()), -0.25);
        assert_eq!(v("|i1", &[0xff]), -1.0);
        assert_eq!(v(">i2", &(-300i16).to_be_bytes()), -300.0);
        assert_eq!(v("<i8", &i64::MIN.to_le_bytes()), i64::MIN as f64);
        assert_eq!(v("<u4", &u32::MAX.to_le_bytes()), u32::MAX as f64);
        assert_eq!(v("|b1", &[1]), 1.0);
        for refused in ["<c16", "<U3", "|O", "<f16", "<m8[s]", ""] {
            assert!(Dtype::parse(refused).is_err(), "{refused}");
        }
    }

    #[test]
    fn declared_sizes_are_not_believed() {
        // A version-2 header claiming 4 GB of header text.
        let mut npy = b"\x93NUMPY\x02\x00".to_vec();
        npy.extend_from_slice(&u32::MAX.to_le_bytes());
        assert!(parse_npy("a".into(), &npy, 16).unwrap_err().contains("more than the"));
        // A shape whose product overflows u64.
        let header = "{'descr': '<f8', 'fortran_order': False, 'shape': (4294967296, 4294967296, 16), }";
        let mut npy = b"\x93NUMPY\x01\x00".to_vec();
        npy.extend_from_slice(&(header.len() as u16).to_le_bytes());
        npy.extend_from_slice(header.as_bytes());
        assert!(parse_npy("a".into(), &npy, 16).unwrap_err().contains("declares shape"));
    }
}
