use super::*;
use crate::MemorySource;
use rtf_core::ClassSet;

/// Frames whose pixels encode (frame, x, y) so any geometric change is visible.
fn source(n: usize, w: usize, h: usize) -> Arc<dyn FrameSource> {
    let frames = (0..n)
        .map(|k| Frame {
            name: format!("{:05}{}", k, if k % 2 == 0 { 'D' } else { 'N' }),
            daytime: Some(if k % 2 == 0 {
                Daytime::Day
            } else {
                Daytime::Night
            }),
            width: w,
            height: h,
            rgb: (0..w * h)
                .flat_map(|i| [(i % w * 9) as u8, (i / w * 9) as u8, k as u8 * 10])
                .collect(),
            thermal: (0..w * h).map(|i| (i % w) as f32 / w as f32).collect(),
            label: Some((0..w * h).map(|i| (i % w % 9) as u8).collect()),
        })
        .collect();
    Arc::new(MemorySource {
        frames,
        class_set: ClassSet::mf(),
    })
}

fn cfg(workers: usize) -> LoaderConfig {
    LoaderConfig {
        batch_size: 3,
        workers,
        prefetch: 2,
        seed: 11,
        ..LoaderConfig::default()
    }
}

type Batches = Vec<(Vec<f32>, Vec<i64>, Vec<String>)>;

fn collect(loader: &Loader, epoch: u64) -> Batches {
    collect_from(loader, epoch, 0)
}

fn collect_from(loader: &Loader, epoch: u64, first_batch: usize) -> Batches {
    loader
        .epoch_from(epoch, first_batch)
        .map(|b| {
            let b = b.unwrap();
            (
                Vec::<f32>::try_from(b.input.flatten(0, -1)).unwrap(),
                Vec::<i64>::try_from(b.target.flatten(0, -1)).unwrap(),
                b.names,
            )
        })
        .collect()
}

#[test]
fn shapes_counts_and_scaling() {
    let loader = Loader::new(
        source(7, 8, 6),
        cfg(2),
        InputConvention::MeanStd {
            mean: 0.5,
            std: 0.5,
        },
    );
    assert_eq!(loader.num_batches(), 3);
    let batches: Vec<Batch> = loader.epoch(0).map(|b| b.unwrap()).collect();
    assert_eq!(batches.len(), 3);
    assert_eq!(batches[0].input.size(), [3, 4, 6, 8]);
    assert_eq!(batches[0].target.size(), [3, 6, 8]);
    assert_eq!(batches[0].target.kind(), tch::Kind::Int64);
    assert_eq!(batches[2].input.size()[0], 1, "last partial batch kept");
    let min = batches[0].input.min().double_value(&[]);
    assert!(
        (-1.0..-0.9).contains(&min),
        "MeanStd maps 0 to -1, got {min}"
    );
    let mut names: Vec<String> = batches.iter().flat_map(|b| b.names.clone()).collect();
    names.sort();
    assert_eq!(names.len(), 7);
    names.dedup();
    assert_eq!(names.len(), 7, "each frame once per epoch");
    let dropping = Loader::new(
        source(7, 8, 6),
        LoaderConfig {
            drop_last: true,
            ..cfg(0)
        },
        InputConvention::UnitRange,
    );
    assert_eq!(dropping.num_batches(), 2);
    assert_eq!(dropping.epoch(0).count(), 2);
}

#[test]
fn same_seed_and_epoch_give_identical_batches_whatever_the_workers() {
    let mut c = cfg(2);
    c.augment = AugmentConfig {
        hflip: true,
        crop: Some(0.1),
        window: None,
        rotation_deg: Some(20.0),
        modality_dropout: Some(0.5),
        ir_scale: Some((0.1, 1.0)),
        brightness: Some(0.2),
        noise_std: Some(0.02),
        scale_crop: None,
    };
    c.resize = Some((12, 8));
    let a = Loader::new(source(7, 16, 12), c.clone(), InputConvention::UnitRange);
    let b = Loader::new(
        source(7, 16, 12),
        LoaderConfig {
            workers: 0,
            ..c.clone()
        },
        InputConvention::UnitRange,
    );
    let e3 = collect(&a, 3);
    assert_eq!(e3, collect(&a, 3));
    assert_eq!(e3, collect(&b, 3), "threads must not change the result");
    assert_ne!(
        e3,
        collect(&a, 4),
        "another epoch shuffles and augments differently"
    );
    let other_seed = Loader::new(
        source(7, 16, 12),
        LoaderConfig { seed: 12, ..c },
        InputConvention::UnitRange,
    );
    assert_ne!(e3, collect(&other_seed, 3));
    // An epoch resumed at batch 3 continues with exactly the batches it had left.
    assert_eq!(collect_from(&a, 3, 3), e3[3..]);
    assert_eq!(collect_from(&b, 3, 3), e3[3..]);
    assert!(collect_from(&a, 3, e3.len()).is_empty());
}

#[test]
fn heatnet_window_cuts_a_whole_pixel_region_of_the_frame() {
    let c = LoaderConfig {
        batch_size: 2,
        augment: AugmentConfig {
            window: Some((5, 3)),
            ..Default::default()
        },
        ..cfg(0)
    };
    let batch = Loader::new(source(2, 8, 6), c, InputConvention::UnitRange)
        .epoch(0)
        .next()
        .unwrap()
        .unwrap();
    assert_eq!(batch.input.size(), [2, 4, 3, 5]);
    let labels = Vec::<i64>::try_from(batch.target.flatten(0, -1)).unwrap();
    // Labels are x % 9 of the source: consecutive columns of one window, unchanged values.
    let x0 = labels[0];
    assert_eq!(&labels[..5], &[x0, x0 + 1, x0 + 2, x0 + 3, x0 + 4]);
    let both = LoaderConfig {
        batch_size: 1,
        augment: AugmentConfig {
            window: Some((5, 3)),
            crop: Some(0.1),
            ..Default::default()
        },
        ..cfg(0)
    };
    assert!(
        Loader::new(source(1, 8, 6), both, InputConvention::UnitRange)
            .epoch(0)
            .next()
            .unwrap()
            .is_err()
    );
}

/// CMX's scale and crop in a batch: the crop's size at any scale, the fill in the padding
/// of a halved frame, its label the loss's "no label" for MF (no ignore id) and the ignore
/// id for a set that has one; refused beside RTFNet's crop.
#[test]
fn scale_crop_pads_with_the_fill_and_no_label() {
    let scale = |scales: Vec<f32>, size| LoaderConfig {
        batch_size: 2,
        resize: Some((16, 12)),
        augment: AugmentConfig {
            scale_crop: Some(augment::ScaleCrop {
                scales,
                size,
                fill: [0.25, 0.5, 0.75, 1.0],
            }),
            ..Default::default()
        },
        ..cfg(0)
    };
    let first = |c: LoaderConfig, classes: ClassSet| {
        let frames = (0..2).map(|k| source(2, 8, 6).load(k).unwrap()).collect();
        let source = Arc::new(MemorySource {
            frames,
            class_set: classes,
        });
        Loader::new(source, c, InputConvention::UnitRange)
            .epoch(0)
            .next()
            .unwrap()
    };
    let batch = first(scale(vec![0.5], None), ClassSet::mf()).unwrap();
    assert_eq!(
        batch.input.size(),
        [2, 4, 12, 16],
        "the crop is the resize's size"
    );
    // Halved: 8×6 content at (4, 3) of 16×12.
    let corner = |c: i64| f64::try_from(batch.input.get(0).get(c).get(0).get(0)).unwrap();
    assert_eq!(
        [corner(0), corner(1), corner(2), corner(3)],
        [0.25, 0.5, 0.75, 1.0]
    );
    let labels = Vec::<i64>::try_from(batch.target.get(0).flatten(0, -1)).unwrap();
    assert_eq!(
        labels.iter().filter(|&&v| v == NO_LABEL).count(),
        16 * 12 - 8 * 6
    );
    assert!(labels[3 * 16 + 4..3 * 16 + 12]
        .iter()
        .all(|&v| (0..9).contains(&v)));
    let freiburg = first(scale(vec![0.5], None), ClassSet::freiburg()).unwrap();
    let labels = Vec::<i64>::try_from(freiburg.target.get(0).flatten(0, -1)).unwrap();
    assert_eq!(labels.iter().filter(|&&v| v == 13).count(), 16 * 12 - 8 * 6);
    let enlarged = first(scale(vec![1.75], Some((10, 8))), ClassSet::mf()).unwrap();
    assert_eq!(enlarged.input.size(), [2, 4, 8, 10]);
    let mut both = scale(vec![1.0], None);
    both.augment.crop = Some(0.1);
    let err = first(both, ClassSet::mf()).unwrap_err().to_string();
    assert!(err.contains("alternatives"), "{err}");
}

#[test]
fn hflip_flips_image_and_label_together() {
    let (w, h) = (8, 4);
    let src = source(1, w, h);
    let plain = collect(
        &Loader::new(
            src.clone(),
            LoaderConfig {
                batch_size: 1,
                ..cfg(0)
            },
            InputConvention::UnitRange,
        ),
        0,
    );
    let (img0, lab0, _) = &plain[0];
    let mirror_f = |v: &[f32], planes: usize| -> Vec<f32> {
        v.chunks(w)
            .take(planes * h)
            .flat_map(|r| r.iter().rev().copied().collect::<Vec<_>>())
            .collect()
    };
    let mirror_i = |v: &[i64]| -> Vec<i64> {
        v.chunks(w)
            .flat_map(|r| r.iter().rev().copied().collect::<Vec<_>>())
            .collect()
    };
    let flipping = Loader::new(
        src,
        LoaderConfig {
            batch_size: 1,
            augment: AugmentConfig {
                hflip: true,
                ..Default::default()
            },
            ..cfg(2)
        },
        InputConvention::UnitRange,
    );
    let (mut flipped, mut kept) = (0, 0);
    for epoch in 0..16 {
        let (img, lab, _) = &collect(&flipping, epoch)[0];
        if img == img0 {
            assert_eq!(lab, lab0, "image kept but label flipped (epoch {epoch})");
            kept += 1;
        } else {
            assert_eq!(img, &mirror_f(img0, 4), "epoch {epoch}");
            assert_eq!(
                lab,
                &mirror_i(lab0),
                "image flipped but label not (epoch {epoch})"
            );
            flipped += 1;
        }
    }
    assert!(flipped > 0 && kept > 0, "flipped {flipped}, kept {kept}");
}

#[test]
fn resize_uses_nearest_labels_and_frame_size_mismatch_is_an_error() {
    let c = LoaderConfig {
        batch_size: 2,
        resize: Some((4, 3)),
        ..cfg(0)
    };
    let batch = Loader::new(source(2, 8, 6), c, InputConvention::UnitRange)
        .epoch(0)
        .next()
        .unwrap()
        .unwrap();
    assert_eq!(batch.input.size(), [2, 4, 3, 4]);
    let labels = Vec::<i64>::try_from(batch.target.flatten(0, -1)).unwrap();
    // Nearest picks source columns 1, 3, 5, 7 whose ids are x % 9.
    assert_eq!(&labels[..4], &[1, 3, 5, 7]);
    let mut frames = vec![
        source(1, 8, 6).load(0).unwrap(),
        source(1, 6, 6).load(0).unwrap(),
    ];
    frames[1].name = "odd".into();
    let mixed: Arc<dyn FrameSource> = Arc::new(MemorySource {
        frames,
        class_set: ClassSet::mf(),
    });
    let err = Loader::new(
        mixed,
        LoaderConfig {
            batch_size: 2,
            ..cfg(0)
        },
        InputConvention::UnitRange,
    )
    .epoch(0)
    .next()
    .unwrap()
    .unwrap_err()
    .to_string();
    assert!(err.contains("set a resize"), "{err}");
}

#[test]
fn errors_stop_the_epoch_and_zero_batch_size_is_reported() {
    let mut frames = vec![source(1, 8, 6).load(0).unwrap(); 4];
    frames[2].rgb.truncate(5);
    let bad: Arc<dyn FrameSource> = Arc::new(MemorySource {
        frames,
        class_set: ClassSet::mf(),
    });
    let items: Vec<_> = Loader::new(
        bad,
        LoaderConfig {
            batch_size: 1,
            shuffle: false,
            ..cfg(2)
        },
        InputConvention::UnitRange,
    )
    .epoch(0)
    .collect();
    assert_eq!(
        items.len(),
        3,
        "two good batches, then the error, then nothing"
    );
    assert!(items[2]
        .as_ref()
        .unwrap_err()
        .to_string()
        .contains("rgb has 5 bytes"));
    let zero = Loader::new(
        source(2, 4, 4),
        LoaderConfig {
            batch_size: 0,
            ..cfg(0)
        },
        InputConvention::UnitRange,
    );
    assert!(zero.epoch(0).next().unwrap().is_err());
}

#[test]
fn dropping_an_epoch_midway_stops_the_worker() {
    let loader = Loader::new(
        source(30, 8, 6),
        LoaderConfig {
            batch_size: 1,
            prefetch: 1,
            ..cfg(2)
        },
        InputConvention::UnitRange,
    );
    let mut it = loader.epoch(0);
    assert!(it.next().unwrap().is_ok());
    drop(it); // must return (joins the producer) instead of hanging
    assert_eq!(loader.epoch(1).count(), 30);
}
