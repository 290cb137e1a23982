//! rtf-data: datasets, synthetic generator, augmentation, input pipeline.
