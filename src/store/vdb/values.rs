//! A node's value buffer as OpenVDB writes it (`io::readCompressedValues`): a metadata byte saying
//! which inactive values were left out, up to two inactive values, a selection mask between them,
//! then the stored values (all of them, or only the active ones under `COMPRESS_ACTIVE_MASK`) as
//! float, double or half, through the grid's codec ([`super::codec`]). Values come out as f32.

use super::codec::{read_data, COMPRESS_ACTIVE_MASK};
use super::error::R;
use super::stream::Stream;
use half::f16;
use std::io::{Read, Seek};

/// How a grid's values are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ValueType {
    Float,
    Double,
}

impl ValueType {
    /// Bytes of one value at full precision (root tiles, background, inactive values).
    pub fn size(self) -> usize {
        match self {
            ValueType::Float => 4,
            ValueType::Double => 8,
        }
    }

    /// One value at full precision, as f32.
    pub fn read<S: Read + Seek>(self, s: &mut Stream<S>, what: &'static str) -> R<f32> {
        Ok(match self {
            ValueType::Float => f32::from_le_bytes(s.array(what)?),
            ValueType::Double => s.f64(what)? as f32,
        })
    }
}

/// The value layout of one grid: its type, whether values were saved as half, its compression.
#[derive(Clone, Copy, Debug)]
pub struct Encoding {
    pub value_type: ValueType,
    pub half: bool,
    pub compression: u32,
    pub background: f32,
}

// The metadata byte (`io::NodeMetadata`).
const NO_MASK_OR_INACTIVE_VALS: u8 = 0;
const NO_MASK_AND_MINUS_BG: u8 = 1;
const NO_MASK_AND_ONE_INACTIVE_VAL: u8 = 2;
const MASK_AND_NO_INACTIVE_VALS: u8 = 3;
const MASK_AND_ONE_INACTIVE_VAL: u8 = 4;
const MASK_AND_TWO_INACTIVE_VALS: u8 = 5;
const NO_MASK_AND_ALL_VALS: u8 = 6;

/// Reads `out.len()` values (a node's whole table) whose active bits are `value_mask`.
pub(crate) fn read_values<S: Read + Seek>(
    s: &mut Stream<S>,
    enc: &Encoding,
    value_mask: &[u64],
    out: &mut [f32],
) -> R<()> {
    let at = s.pos();
    let meta = s.u8("a node's value metadata")?;
    if meta > NO_MASK_AND_ALL_VALS {
        return Err(s.malformed(
            "a node's value metadata",
            at,
            format!("unknown value metadata {meta} (expected 0 to 6)"),
        ));
    }
    let bg = enc.background;
    let mut inactive1 = bg;
    // NO_MASK_AND_MINUS_BG (and the masked kinds, unless they carry their own) use -background.
    let mut inactive0 = if meta == NO_MASK_OR_INACTIVE_VALS { bg } else { -bg };
    debug_assert!(meta != NO_MASK_AND_MINUS_BG || inactive0 == -bg);
    if matches!(meta, NO_MASK_AND_ONE_INACTIVE_VAL | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS) {
        inactive0 = enc.value_type.read(s, "a node's inactive value")?;
        if meta == MASK_AND_TWO_INACTIVE_VALS {
            inactive1 = enc.value_type.read(s, "a node's second inactive value")?;
        }
    }
    let selection =
        if matches!(meta, MASK_AND_NO_INACTIVE_VALS | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS) {
            Some(s.mask(value_mask.len(), "a node's selection mask")?)
        } else {
            None
        };
    let active = |i: usize| value_mask[i >> 6] >> (i & 63) & 1 == 1;
    let masked = enc.compression & COMPRESS_ACTIVE_MASK != 0 && meta != NO_MASK_AND_ALL_VALS;
    let stored = if masked { value_mask.iter().map(|w| w.count_ones() as usize).sum() } else { out.len() };
    let size = if enc.half { 2 } else { enc.value_type.size() };
    let mut bytes = vec![0u8; stored * size];
    // OpenVDB's HalfWriter writes nothing at all (not even a chunk size) for zero values.
    if !(enc.half && stored == 0) {
        read_data(s, enc.compression, &mut bytes)?;
    }
    let value = |k: usize| -> f32 {
        let b = &bytes[k * size..(k + 1) * size];
        match (enc.half, enc.value_type) {
            (true, _) => f16::from_le_bytes([b[0], b[1]]).to_f32(),
            (false, ValueType::Float) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            (false, ValueType::Double) => f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f32,
        }
    };
    if stored == out.len() {
        for (i, o) in out.iter_mut().enumerate() {
            *o = value(i);
        }
    } else {
        let mut k = 0;
        for (i, o) in out.iter_mut().enumerate() {
            *o = if active(i) {
                k += 1;
                value(k - 1)
            } else if selection.as_ref().is_some_and(|m| m[i >> 6] >> (i & 63) & 1 == 1) {
                inactive1
            } else {
                inactive0
            };
        }
    }
    Ok(())
}
