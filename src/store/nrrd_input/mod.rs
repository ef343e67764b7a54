//! NRRD input (`.nhdr` with a detached data file, or `.nrrd` with the data attached): a density
//! volume from a header ([`header`]) with raw or gzip samples of float, double, uchar or ushort.
//! The samples are decoded in one sequential pass (gzip cannot be read at random) into a
//! little-endian f32 file in the store directory, which the raw importer then maps brick by brick
//! ([`crate::store::import::raw_density`]): memory stays bounded whatever the volume's size.

pub mod header;

use crate::solver::cancel::{self, CancelFlag, Stoppable};
use crate::store::StoreError;
use header::{DataSource, Encoding, NrrdHeader, SampleType};
use std::io::{BufReader, Read, Seek, SeekFrom, Write};
use std::path::Path;

/// The longest header read (an attached header is followed by the data).
const MAX_HEADER: u64 = 1 << 20;

/// Reads and checks the header of `path`.
pub fn nrrd_header(path: &Path) -> Result<NrrdHeader, StoreError> {
    let file = crate::input::open(path)?;
    let mut bytes = Vec::new();
    file.take(MAX_HEADER).read_to_end(&mut bytes).map_err(StoreError::io(path, "read the NRRD header of"))?;
    header::parse(path, &bytes).map_err(|(field, problem)| StoreError::Nrrd {
        path: path.to_path_buf(),
        field,
        problem,
    })
}

/// Decodes every sample of `h` (x fastest) as f32 and hands them to `sink` in chunks. Checks that
/// the data holds exactly the samples the header promises (for raw data: at least, after `byte skip`).
pub fn decode(
    path: &Path,
    h: &NrrdHeader,
    sink: impl FnMut(&[f32]) -> Result<(), StoreError>,
) -> Result<(), StoreError> {
    decode_until(path, h, None, sink)
}

/// [`decode`], stopping with [`StoreError::Cancelled`] once `cancel` is raised: it is looked at
/// before each chunk of samples and at every read of the file (a large volume takes many
/// seconds to decode, and a gzip stream can promise any number of samples).
pub fn decode_until(
    path: &Path,
    h: &NrrdHeader,
    cancel: Option<CancelFlag>,
    mut sink: impl FnMut(&[f32]) -> Result<(), StoreError>,
) -> Result<(), StoreError> {
    match decode_samples(path, h, cancel, &mut sink) {
        Err(_) if cancel::raised(cancel) => Err(StoreError::Cancelled),
        r => r,
    }
}

fn decode_samples(
    path: &Path,
    h: &NrrdHeader,
    cancel: Option<CancelFlag>,
    sink: &mut impl FnMut(&[f32]) -> Result<(), StoreError>,
) -> Result<(), StoreError> {
    let (data_path, offset) = match &h.data {
        DataSource::Detached(p) => (p.as_path(), 0),
        DataSource::Attached(at) => (path, *at),
    };
    // Opened through the input checks: the header names this file, so it could name a FIFO, or
    // (in a confined solve) a file outside the data root.
    let mut file = crate::input::open(data_path)?;
    let skip = if h.encoding == Encoding::Raw { offset + h.byte_skip } else { offset };
    file.seek(SeekFrom::Start(skip)).map_err(StoreError::io(data_path, "seek in"))?;
    let reader = BufReader::with_capacity(1 << 20, Stoppable { inner: file, cancel });
    let mut reader: Box<dyn Read> = match h.encoding {
        Encoding::Raw => Box::new(reader),
        Encoding::Gzip => Box::new(flate2::read::MultiGzDecoder::new(reader)),
    };
    let bad = |problem: String| StoreError::Nrrd { path: data_path.to_path_buf(), field: "data".into(), problem };
    if h.encoding == Encoding::Gzip && h.byte_skip > 0 {
        std::io::copy(&mut (&mut reader).take(h.byte_skip), &mut std::io::sink())
            .map_err(|e| bad(format!("cannot skip {} bytes: {e}", h.byte_skip)))?;
    }
    let total = h.dims.iter().product::<u64>();
    let size = h.sample.size();
    const CHUNK: u64 = 1 << 18;
    let mut bytes = vec![0u8; CHUNK as usize * size];
    let mut values = vec![0f32; CHUNK as usize];
    let mut done = 0u64;
    while done < total {
        if cancel::raised(cancel) {
            return Err(StoreError::Cancelled);
        }
        let n = CHUNK.min(total - done) as usize;
        let b = &mut bytes[..n * size];
        reader.read_exact(b).map_err(|e| {
            bad(if e.kind() == std::io::ErrorKind::UnexpectedEof {
                format!("the data ends after {done} of the {total} samples the header promises (or is cut short)")
            } else {
                format!("cannot read the samples: {e}")
            })
        })?;
        for (v, c) in values[..n].iter_mut().zip(b.chunks_exact(size)) {
            *v = match (h.sample, h.big_endian) {
                (SampleType::U8, _) => f32::from(c[0]),
                (SampleType::U16, false) => f32::from(u16::from_le_bytes([c[0], c[1]])),
                (SampleType::U16, true) => f32::from(u16::from_be_bytes([c[0], c[1]])),
                (SampleType::F32, false) => f32::from_le_bytes([c[0], c[1], c[2], c[3]]),
                (SampleType::F32, true) => f32::from_be_bytes([c[0], c[1], c[2], c[3]]),
                (SampleType::F64, big) => {
                    let a = [c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]];
                    (if big { f64::from_be_bytes(a) } else { f64::from_le_bytes(a) }) as f32
                }
            };
        }
        sink(&values[..n])?;
        done += n as u64;
    }
    if h.encoding == Encoding::Gzip {
        let mut extra = [0u8; 1];
        if reader.read(&mut extra).map_err(|e| bad(format!("corrupt gzip data: {e}")))? != 0 {
            return Err(bad(format!("the gzip data holds more than the {total} samples the header promises")));
        }
    }
    Ok(())
}

/// Decodes `path`'s samples into `out` as little-endian f32 (x fastest): the raw volume the brick
/// store imports. Written under a temporary name and renamed when complete; stopped (and the
/// temporary removed) once `cancel` is raised.
pub fn convert_to_raw(path: &Path, h: &NrrdHeader, out: &Path, cancel: Option<CancelFlag>) -> Result<(), StoreError> {
    // The writer closure can only return io errors; a decoding error is parked here and returned.
    let mut failed = None;
    let r = crate::store::write_atomic_io(out, |w| {
        let r = decode_until(path, h, cancel, |v| {
            w.write_all(bytemuck::cast_slice(v)).map_err(StoreError::io(out, "write"))
        });
        match r {
            Ok(()) => Ok(()),
            Err(e) => {
                failed = Some(e);
                Err(std::io::Error::other("decoding failed"))
            }
        }
    });
    if let Some(e) = failed {
        return Err(e);
    }
    r.map_err(|(action, source)| StoreError::Io { path: out.to_path_buf(), action, source })
}
