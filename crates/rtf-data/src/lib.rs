//! rtf-data: datasets, synthetic generator, augmentation, input pipeline.
//!
//! - [`open`] recognises a dataset root once into a [`Dataset`] (layout, class set, thermal
//!   rule, splits) that every command and training phase takes ([`dataset`]).
//! - [`MfDataset`] reads the MF layout (spec §1); every split implements [`FrameSource`].
//! - [`Loader`] turns a frame source into shuffled, augmented `tch` batches.
//! - [`synth`] writes synthetic datasets in the real layouts.

pub mod augment;
pub mod bdd;
pub mod conditions;
pub mod dataset;
pub mod described;
pub mod description;
pub mod error;
pub mod fingerprint;
pub mod frame;
pub mod freiburg;
pub mod fuzzing;
pub mod hash;
pub mod images;
pub mod inspect;
pub mod layouts;
pub mod loader;
pub mod mf;
pub mod npy;
pub mod pattern;
pub mod planes;
pub mod pngio;
pub mod scale_crop;
pub mod split_list;
pub mod synth;
pub mod thermal;
pub mod tiffio;
pub mod trained_on;
pub mod unknown;

pub use augment::{resize_frame, AugmentConfig, ScaleCrop};
pub use dataset::{open, Dataset, DatasetFormat};
pub use described::{DescribedDataset, DescribedSplit};
pub use description::DatasetDescription;
pub use error::DataError;
pub use fingerprint::{fingerprint, Fingerprint, SplitFingerprint};
pub use frame::{Frame, FrameSource, MemorySource};
pub use freiburg::{FreiburgPart, FreiburgPreprocess, FreiburgSplit};
pub use loader::{Batch, Loader, LoaderConfig};
pub use mf::{MfDataset, MfSplit};
pub use trained_on::TrainedOn;

#[cfg(test)]
mod sequence_tests;
#[cfg(test)]
pub(crate) mod testutil;
