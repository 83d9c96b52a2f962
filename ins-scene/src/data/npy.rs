//! Reading and writing NumPy `.npy` and `.npz` float arrays, with errors that name the file.
//!
//! Arrays are read whole into memory after checking that the header's shape fits the bytes
//! actually present, so a corrupt header cannot ask for a huge allocation.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::path::Path;

use npyz::{TypeChar, WriterBuilder};

use super::DataError;

/// A float array read from NumPy: its shape and values (as f64, C order).
#[derive(Clone, Debug, PartialEq)]
pub struct Array {
    /// Shape.
    pub shape: Vec<usize>,
    /// Values in C (row-major) order.
    pub data: Vec<f64>,
}

impl Array {
    /// The value at a 2-D index.
    pub fn at2(&self, r: usize, c: usize) -> f64 {
        self.data[r * self.shape[1] + c]
    }
}

/// Reads a `.npy` file holding a float32 or float64 array.
pub fn read_npy(path: &Path) -> Result<Array, DataError> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    parse_npy(&bytes).map_err(|msg| DataError::npy(path, msg))
}

/// Reads every array of a `.npz` archive, keyed by name (without `.npy`).
pub fn read_npz(path: &Path) -> Result<BTreeMap<String, Array>, DataError> {
    let file = std::fs::File::open(path).map_err(|e| DataError::io(path, e))?;
    let mut zip = zip::ZipArchive::new(std::io::BufReader::new(file))
        .map_err(|e| DataError::npy(path, format!("not a zip archive: {e}")))?;
    let mut out = BTreeMap::new();
    for i in 0..zip.len() {
        let mut entry = zip
            .by_index(i)
            .map_err(|e| DataError::npy(path, format!("entry {i}: {e}")))?;
        let name = entry.name().to_string();
        let Some(stem) = name.strip_suffix(".npy") else {
            continue;
        };
        let mut bytes = Vec::new();
        entry
            .read_to_end(&mut bytes)
            .map_err(|e| DataError::npy(path, format!("{name}: {e}")))?;
        let arr =
            parse_npy(&bytes).map_err(|msg| DataError::npy(path, format!("{name}: {msg}")))?;
        out.insert(stem.to_string(), arr);
    }
    Ok(out)
}

/// Parses the bytes of one `.npy` file.
fn parse_npy(bytes: &[u8]) -> Result<Array, String> {
    let npy = npyz::NpyFile::new(bytes).map_err(|e| format!("bad header: {e}"))?;
    let shape: Vec<usize> = npy.shape().iter().map(|&d| d as usize).collect();
    let (len, size) = match npy.dtype() {
        npyz::DType::Plain(ts)
            if ts.type_char() == TypeChar::Float && matches!(ts.size_field(), 4 | 8) =>
        {
            (npy.len() as usize, ts.size_field() as usize)
        }
        other => return Err(format!("dtype {} is not float32 or float64", other.descr())),
    };
    if len.checked_mul(size).is_none_or(|n| n > bytes.len()) {
        return Err(format!(
            "shape {shape:?} needs {len} values but the file is only {} bytes",
            bytes.len()
        ));
    }
    let fortran = npy.order() == npyz::Order::Fortran;
    let data: Vec<f64> = if size == 8 {
        npy.into_vec::<f64>()
            .map_err(|e| format!("truncated data: {e}"))?
    } else {
        npy.into_vec::<f32>()
            .map_err(|e| format!("truncated data: {e}"))?
            .into_iter()
            .map(f64::from)
            .collect()
    };
    if data.len() != len {
        return Err(format!("expected {len} values, read {}", data.len()));
    }
    let data = if fortran && shape.len() > 1 {
        fortran_to_c(&data, &shape)
    } else {
        data
    };
    Ok(Array { shape, data })
}

/// Reorders Fortran-order (column-major) data to C order.
fn fortran_to_c(data: &[f64], shape: &[usize]) -> Vec<f64> {
    let n = data.len();
    let mut out = vec![0.0; n];
    let mut idx = vec![0usize; shape.len()];
    for (c_pos, slot) in out.iter_mut().enumerate() {
        let mut rem = c_pos;
        for k in (0..shape.len()).rev() {
            idx[k] = rem % shape[k];
            rem /= shape[k];
        }
        let mut f_pos = 0;
        let mut stride = 1;
        for k in 0..shape.len() {
            f_pos += idx[k] * stride;
            stride *= shape[k];
        }
        *slot = data[f_pos];
    }
    out
}

/// Writes a float64 `.npy` file in C order.
pub fn write_npy(path: &Path, shape: &[usize], data: &[f64]) -> Result<(), DataError> {
    let file = std::fs::File::create(path).map_err(|e| DataError::io(path, e))?;
    let shape64: Vec<u64> = shape.iter().map(|&d| d as u64).collect();
    let mut w = npyz::WriteOptions::<f64>::new()
        .default_dtype()
        .shape(&shape64)
        .writer(std::io::BufWriter::new(file))
        .begin_nd()
        .map_err(|e| DataError::io(path, e))?;
    w.extend(data.iter().copied())
        .map_err(|e| DataError::io(path, e))?;
    w.finish().map_err(|e| DataError::io(path, e))
}

/// Writes a `.npz` archive (uncompressed, like `numpy.savez`) of float64 arrays.
pub fn write_npz(path: &Path, arrays: &[(String, Vec<usize>, Vec<f64>)]) -> Result<(), DataError> {
    let file = std::fs::File::create(path).map_err(|e| DataError::io(path, e))?;
    let mut npz = zip::ZipWriter::new(std::io::BufWriter::new(file));
    let zip_error = |e: zip::result::ZipError| DataError::io(path, std::io::Error::other(e));
    for (name, shape, data) in arrays {
        let shape64: Vec<u64> = shape.iter().map(|&d| d as u64).collect();
        let mut bytes = Vec::new();
        let mut w = npyz::WriteOptions::<f64>::new()
            .default_dtype()
            .shape(&shape64)
            .writer(&mut bytes)
            .begin_nd()
            .map_err(|e| DataError::io(path, e))?;
        w.extend(data.iter().copied())
            .map_err(|e| DataError::io(path, e))?;
        w.finish().map_err(|e| DataError::io(path, e))?;
        let options = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Stored);
        npz.start_file(format!("{name}.npy"), options)
            .map_err(zip_error)?;
        npz.write_all(&bytes).map_err(|e| DataError::io(path, e))?;
    }
    npz.finish()
        .map_err(zip_error)?
        .flush()
        .map_err(|e| DataError::io(path, e))
}
