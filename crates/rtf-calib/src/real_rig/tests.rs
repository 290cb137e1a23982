use super::*;

#[test]
fn unmeasured_bands_follow_the_common_profile() {
    let m = |v: &[f64], known: &[usize]| -> Vec<Option<f64>> {
        (0..v.len())
            .map(|i| known.contains(&i).then_some(v[i]))
            .collect()
    };
    let day = [-3.0, -2.0, -1.0, 0.0, 1.0, -1.0, -4.0, -7.0];
    let scenes = vec![
        m(&day, &[0, 1, 2, 3, 4, 5, 6, 7]),
        m(&day.map(|v| v + 2.0), &[0, 1, 2, 3, 4, 5, 6, 7]),
        // A night scene measured at the top only, 1 px above the profile.
        m(&day.map(|v| v + 1.0), &[0, 1, 2, 3]),
    ];
    let profile = parallax_profile(&scenes);
    // Relative to the middle bands' mean (0).
    assert_eq!(profile, day.to_vec());
    let night = bands_from_profile(&scenes[2], &profile);
    for (got, want) in night.iter().zip(day.map(|v| v + 1.0)) {
        assert!((got - want).abs() < 1e-12, "{night:?}");
    }
    // Nothing measured: the profile itself.
    assert_eq!(bands_from_profile(&[None; 8], &profile), day.to_vec());
}

#[test]
fn parallax_shift_interpolates_between_band_centres() {
    let bands = [0.0, 1.0, 3.0, -1.0, 0.0, 0.0, 2.0, 4.0];
    // Band b's centre is row 60·b + 29.5.
    assert_eq!(parallax_shift(&bands, 89.5), 1.0);
    assert_eq!(parallax_shift(&bands, 119.5), 2.0);
    assert_eq!(parallax_shift(&bands, 179.5), 1.0);
    assert_eq!(parallax_shift(&bands, 449.5), 4.0);
    // Constant past the first and last centres.
    assert_eq!(parallax_shift(&bands, 0.0), 0.0);
    assert_eq!(parallax_shift(&bands, 479.0), 4.0);
    // Every table row names a registered scene.
    for (scene, _) in MSRS_PARALLAX {
        assert!(MSRS_REGISTRATION.iter().any(|r| r.0 == scene), "{scene}");
    }
}

#[test]
fn corridor_rays_hit_the_nearest_wall() {
    let c = Corridor {
        ground_y: 1.5,
        left_x: -4.0,
        right_x: 5.0,
        end_z: 30.0,
    };
    let p = c.hit([0.0; 3], [0.0, 0.1, 1.0]).unwrap();
    assert!((p[1] - 1.5).abs() < 1e-9 && (p[2] - 15.0).abs() < 1e-9);
    let p = c.hit([0.0; 3], [0.5, -0.01, 1.0]).unwrap();
    assert!((p[0] - 5.0).abs() < 1e-9);
    let p = c.hit([0.0; 3], [0.0, -0.01, 1.0]).unwrap();
    assert!((p[2] - 30.0).abs() < 1e-9);
}

#[test]
fn real_rig_thermal_is_the_real_image_through_the_true_camera() {
    let Some(data) = default_data_dir() else {
        eprintln!("skipped: ../shared/data not found");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = RealRigConfig::new(&data, 3, 160, 2);
    cfg.daylight = Daylight::Day;
    let real = write_real_rig(dir.path(), &cfg).unwrap();
    let frames = crate::frames::load_frames(&real.rig, &mut |w| panic!("{w}")).unwrap();
    assert_eq!(frames.len(), 2);
    // Warping the thermal image into the RGB view with the truth reproduces the real
    // thermal scene (MSRS ir resampled to the RGB grid) far better than the nominal start.
    let src = resample(
        &{
            let p = read_thermal_raw(&data.join(format!("msrs-samples/ir/{}.png", real.scenes[0])))
                .unwrap();
            register_msrs_ir(
                &real.scenes[0],
                &Plane::new(
                    p.width,
                    p.height,
                    p.data.iter().map(|v| v / 255.0).collect(),
                ),
            )
        },
        160,
        120,
    );
    let thermal = read_thermal_raw(&real.rig.frames[0].thermal).unwrap();
    let f = &frames[0];
    let nominal = crate::optimize::initial_params(&real.rig);
    let err = |calib: &Calibration| {
        let (mut sum, mut n) = (0.0, 0);
        for v in 10..110 {
            for u in 10..150 {
                let d = f.depth.at(u, v) as f64;
                let (tu, tv) = calib
                    .map_pixel(&real.rig.rgb, u as f64, v as f64, d)
                    .unwrap();
                if tu < 1.0 || tv < 1.0 || tu > 158.0 || tv > 126.0 {
                    continue;
                }
                let t = bilinear_clamped(&thermal, tu, tv) / 255.0;
                sum += (t - src.at(u, v)).abs() as f64;
                n += 1;
            }
        }
        sum / n as f64
    };
    let at_truth = err(&real.truth);
    let at_start = err(&crate::model::to_calibration(&nominal));
    assert!(at_truth < 0.05, "mean |difference| at the truth {at_truth}");
    assert!(
        at_start > 2.0 * at_truth,
        "start {at_start} vs truth {at_truth}"
    );
}
