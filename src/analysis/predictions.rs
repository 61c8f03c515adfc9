//! A predictions file as numpy writes it (`np.savez` or `np.savez_compressed`:
//! a zip of `.npy` arrays), read into named arrays of f64 for `evaluate`.
//! Any real or integer dtype (or bool) of either byte order is accepted, in
//! C or Fortran order (a transposed array is saved in Fortran order); the
//! values come back in C order.

use npyz::{DType, NpyFile, Order, TypeChar};
use std::io::Read;
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

/// Reads every array of the `.npz` at `path`, in archive order. Errors name
/// the file and, where one is at fault, the array.
pub fn read_npz(path: &Path) -> Result<Vec<NamedArray>, String> {
    let file = std::fs::File::open(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let mut archive = zip::ZipArchive::new(std::io::BufReader::new(file))
        .map_err(|e| format!("{}: not an .npz file (numpy's np.savez writes one): {e}", path.display()))?;
    let mut arrays = Vec::with_capacity(archive.len());
    for index in 0..archive.len() {
        let mut entry = archive.by_index(index).map_err(|e| format!("{}: entry {index}: {e}", path.display()))?;
        if entry.is_dir() {
            continue;
        }
        let entry_name = entry.name().to_string();
        let Some(name) = npyz::npz::array_name_from_file_name(&entry_name).map(str::to_string) else {
            return Err(format!("{}: holds {entry_name:?}, which is no .npy array", path.display()));
        };
        let mut bytes = Vec::with_capacity(entry.size() as usize);
        entry.read_to_end(&mut bytes).map_err(|e| format!("{}: array {name:?}: {e}", path.display()))?;
        let array = parse_npy(name, &bytes).map_err(|e| format!("{}: {e}", path.display()))?;
        arrays.push(array);
    }
    Ok(arrays)
}

/// One `.npy` file's bytes as a [`NamedArray`].
fn parse_npy(name: String, bytes: &[u8]) -> Result<NamedArray, String> {
    let bad = |what: &dyn std::fmt::Display| format!("array {name:?}: {what}");
    let npy = NpyFile::new(bytes).map_err(|e| bad(&e))?;
    let shape: Vec<usize> = npy.shape().iter().map(|&d| d as usize).collect();
    let order = npy.order();
    let dtype = npy.dtype();
    let DType::Plain(ty) = &dtype else {
        return Err(bad(&format!("has a structured dtype ({}); give plain numbers", dtype.descr())));
    };
    let read = |e: std::io::Error| bad(&e);
    let values: Vec<f64> = match (ty.type_char(), ty.size_field()) {
        (TypeChar::Float, 8) => npy.into_vec::<f64>().map_err(read)?,
        (TypeChar::Float, 4) => npy.into_vec::<f32>().map_err(read)?.into_iter().map(f64::from).collect(),
        (TypeChar::Int, 1) => npy.into_vec::<i8>().map_err(read)?.into_iter().map(f64::from).collect(),
        (TypeChar::Int, 2) => npy.into_vec::<i16>().map_err(read)?.into_iter().map(f64::from).collect(),
        (TypeChar::Int, 4) => npy.into_vec::<i32>().map_err(read)?.into_iter().map(f64::from).collect(),
        (TypeChar::Int, 8) => npy.into_vec::<i64>().map_err(read)?.into_iter().map(|v| v as f64).collect(),
        (TypeChar::Uint, 1) => npy.into_vec::<u8>().map_err(read)?.into_iter().map(f64::from).collect(),
        (TypeChar::Uint, 2) => npy.into_vec::<u16>().map_err(read)?.into_iter().map(f64::from).collect(),
        (TypeChar::Uint, 4) => npy.into_vec::<u32>().map_err(read)?.into_iter().map(f64::from).collect(),
        (TypeChar::Uint, 8) => npy.into_vec::<u64>().map_err(read)?.into_iter().map(|v| v as f64).collect(),
        (TypeChar::Bool, 1) => npy.into_vec::<bool>().map_err(read)?.into_iter().map(|b| b as u8 as f64).collect(),
        _ => return Err(bad(&format!("has dtype {}; give floats, integers or bools", dtype.descr()))),
    };
    let values = match order {
        Order::C => values,
        Order::Fortran => fortran_to_c(&values, &shape),
    };
    Ok(NamedArray { name, shape, values })
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
}
