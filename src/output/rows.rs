//! Plain CSV rows written straight into a byte buffer: the logs' fields are
//! numbers and names, so the csv crate's per-field quoting machinery was most
//! of the cost of `poses.csv` (about a tenth of a poses-only `gen`). The
//! bytes are those a `csv::Writer` with default settings writes: fields
//! separated by `,`, rows ended by `\n`, a field quoted (and its quotes
//! doubled) only when it holds `,`, `"`, `\r` or `\n`.

use super::number::{push_fixed, push_int};
use std::io::{self, Write};

/// Bytes buffered before they go to the output.
const FLUSH_AT: usize = 1 << 15;

/// A CSV file being written row by row; owns the output and one row's worth
/// (or a few) of unwritten bytes.
pub struct Rows<W: Write> {
    out: W,
    buffer: Vec<u8>,
    row_has_field: bool,
}

impl<W: Write> Rows<W> {
    /// A file whose first row is `header`.
    pub fn new(out: W, header: &[&str]) -> io::Result<Self> {
        let mut rows = Rows { out, buffer: Vec::with_capacity(FLUSH_AT + 256), row_has_field: false };
        for name in header {
            rows.text(name);
        }
        rows.end()?;
        Ok(rows)
    }

    fn separate(&mut self) {
        if self.row_has_field {
            self.buffer.push(b',');
        }
        self.row_has_field = true;
    }

    /// An unsigned integer field.
    pub fn int(&mut self, n: u64) -> &mut Self {
        self.separate();
        push_int(&mut self.buffer, n);
        self
    }

    /// `x` rounded to `decimals` places (see [`push_fixed`]).
    pub fn fixed(&mut self, x: f64, decimals: u32) -> &mut Self {
        self.separate();
        push_fixed(&mut self.buffer, x, decimals);
        self
    }

    /// A text field, quoted as the csv crate quotes it when it must be.
    pub fn text(&mut self, s: &str) -> &mut Self {
        self.separate();
        if s.bytes().any(|b| matches!(b, b',' | b'"' | b'\r' | b'\n')) {
            self.buffer.push(b'"');
            for b in s.bytes() {
                if b == b'"' {
                    self.buffer.push(b'"');
                }
                self.buffer.push(b);
            }
            self.buffer.push(b'"');
        } else {
            self.buffer.extend_from_slice(s.as_bytes());
        }
        self
    }

    /// Ends the row.
    pub fn end(&mut self) -> io::Result<()> {
        self.buffer.push(b'\n');
        self.row_has_field = false;
        if self.buffer.len() >= FLUSH_AT {
            self.out.write_all(&self.buffer)?;
            self.buffer.clear();
        }
        Ok(())
    }

    /// Writes what is buffered, flushes the output and returns it.
    pub fn finish(mut self) -> io::Result<W> {
        self.out.write_all(&self.buffer)?;
        self.out.flush()?;
        Ok(self.out)
    }
}

/// `fields` (two or more) as one row without its line end: the cells a
/// writer formats once and repeats.
pub fn cells(fields: &[&str]) -> Vec<u8> {
    debug_assert!(fields.len() > 1, "the csv crate quotes a lone empty field");
    let mut row = Rows { out: io::sink(), buffer: Vec::new(), row_has_field: false };
    for field in fields {
        row.text(field);
    }
    row.buffer
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same rows through `Rows` and through the csv crate give the same
    /// bytes, quoting included.
    #[test]
    fn bytes_match_the_csv_crate() {
        let texts = ["plain", "", "AC/W/straight", "a,b", "say \"hi\"", "two\nlines", "cr\r", " spaced "];
        let mut ours = Rows::new(Vec::new(), &["n", "x", "name"]).unwrap();
        let mut theirs = csv::WriterBuilder::new().has_headers(false).from_writer(Vec::new());
        theirs.write_record(["n", "x", "name"]).unwrap();
        let mut rows = 0;
        for (k, text) in texts.iter().enumerate() {
            let x = k as f64 * -1.37 + 0.5;
            ours.int(k as u64).fixed(x, 3).text(text);
            ours.end().unwrap();
            let mut formatted = Vec::new();
            push_fixed(&mut formatted, x, 3);
            theirs.write_record([k.to_string().as_bytes(), &formatted, text.as_bytes()]).unwrap();
            rows += 1;
        }
        let ours_bytes = ours.finish().unwrap();
        let theirs_bytes = theirs.into_inner().unwrap();
        assert_eq!(rows, texts.len());
        let mut quoted = csv::WriterBuilder::new().has_headers(false).from_writer(Vec::new());
        quoted.write_record(texts).unwrap();
        let mut quoted = quoted.into_inner().unwrap();
        assert_eq!(quoted.pop(), Some(b'\n'));
        assert_eq!(cells(&texts), quoted);
        assert_eq!(String::from_utf8(ours_bytes).unwrap(), String::from_utf8(theirs_bytes).unwrap());
    }
}
