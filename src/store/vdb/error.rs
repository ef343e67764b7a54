//! What can be wrong with a VDB file, said in words a user can act on. Every error that comes from
//! the bytes names what was being read and the byte offset where it went wrong; the file's path is
//! added by the caller (see [`crate::store::StoreError::Vdb`]).

/// A VDB file that cannot be read, or a grid in it that lpm cannot use.
#[derive(Debug, thiserror::Error)]
pub enum VdbError {
    #[error("cannot read the file: {0}")]
    Io(#[source] std::io::Error),

    #[error("not an OpenVDB file: the first 8 bytes are not the VDB magic number")]
    NotVdb,

    #[error("the file is truncated: it ends at byte {len}, inside {what} (which starts at byte {offset})")]
    Truncated { what: &'static str, offset: u64, len: u64 },

    #[error("malformed {what} at byte {offset}: {message}")]
    Malformed { what: &'static str, offset: u64, message: String },

    /// A size the file claims that cannot be believed: more than the format allows, or more memory
    /// than the host has available for something read whole.
    #[error("{what} at byte {offset} claims {claimed} bytes, {limit}")]
    Claimed { what: &'static str, offset: u64, claimed: u64, limit: String },

    #[error(
        "OpenVDB file format version {0} is not supported: lpm reads versions 222 to 224 \
         (written by OpenVDB 3.0 and later)"
    )]
    Version(u32),

    #[error("the file has no grid named \"{name}\"; its grids are: {available}")]
    NoGrid { name: String, available: String },

    #[error("grid \"{name}\" has type {grid_type}; lpm reads scalar float, half and double grids (Tree_float_5_4_3, Tree_double_5_4_3)")]
    GridType { name: String, grid_type: String },

    #[error("grid \"{name}\" is an instance of grid \"{parent}\"; instanced grids are not supported: save the file without instancing")]
    Instance { name: String, parent: String },

    #[error("grid \"{name}\": {message}")]
    Transform { name: String, message: String },
}

pub(crate) type R<T> = Result<T, VdbError>;
