//! Tests of the units and layers of [`super`].

use super::*;
use crate::fast::unit::WeightForm;
use crate::fast::{FoldOptions, InferenceKernels, Layout, Precision};
use nn::ModuleT;
use tch::Device;

/// `unit` folded as `options` say.
fn fold_as(unit: &ConvBnAct, options: FoldOptions) -> ConvBnAct {
    unit.folded(&Folder::new(&options))
}

/// `unit` folded for `precision`, channels-last, the unmeasured kernels.
fn fold(unit: &ConvBnAct, precision: Precision) -> ConvBnAct {
    fold_as(unit, FoldOptions::new(precision))
}

/// bf16 options with bf16's convolutions emulated (`true`) or native.
fn bf16_emulated(emulated: bool) -> FoldOptions {
    let bf16_convolutions = match emulated {
        true => rtf_amp::Bf16Convolutions::Emulated,
        false => rtf_amp::Bf16Convolutions::Native,
    };
    FoldOptions::new(Precision::Bf16).kernels(InferenceKernels {
        bf16_convolutions,
        ..InferenceKernels::unmeasured()
    })
}

/// (output, input gradient, weight gradient, bias gradient) of `conv` on fresh leaves
/// copied from `x`, `w`, `b`, with a fixed upstream gradient.
fn conv_and_gradients(
    x: &Tensor,
    w: &Tensor,
    b: &Tensor,
    conv: impl Fn(&Tensor, &Tensor, &Tensor) -> Tensor,
) -> [Tensor; 4] {
    let leaf = |t: &Tensor| t.detach().copy().set_requires_grad(true);
    let (x, w, b) = (leaf(x), leaf(w), leaf(b));
    let y = conv(&x, &w, &b);
    let upstream =
        Tensor::linspace(-1.0, 1.0, y.numel() as i64, (Kind::Float, Device::Cpu)).reshape(y.size());
    (y.to_kind(Kind::Float) * upstream)
        .sum(Kind::Float)
        .backward();
    [y.detach(), x.grad(), w.grad(), b.grad()]
}

/// The root of `vs` as a path of a build with the default options.
fn root(vs: &nn::VarStore) -> Path<'_> {
    Path::from(vs.root())
}

#[test]
fn emulated_bf16_convolution_has_a_native_kernels_numbers() {
    tch::manual_seed(3);
    for (transposed, stride, dilation, groups) in
        [(false, 1, 1, 1), (false, 2, 2, 2), (true, 2, 1, 1)]
    {
        let g = Geometry {
            stride,
            padding: 1,
            dilation,
            groups,
            transposed,
        };
        let x = Tensor::randn([2, 4, 9, 11], (Kind::Float, Device::Cpu));
        let w_dims = match transposed {
            false => [6, 4 / groups, 3, 3],
            true => [4, 6, 3, 3],
        };
        let w = Tensor::randn(w_dims, (Kind::Float, Device::Cpu)) * 0.3;
        let b = Tensor::randn([6], (Kind::Float, Device::Cpu));
        let plain = |x: &Tensor, w: &Tensor, b: &Tensor| match transposed {
            false => x.conv2d(w, Some(b), [stride], [1], [dilation], groups),
            true => x.conv_transpose2d(w, Some(b), [stride], [1], [0], groups, [dilation]),
        };
        let emulated = conv_and_gradients(&x, &w, &b, |x, w, b| {
            bf16_emulated_convolution(x, w, Some(b), g)
        });
        // Its definition: fp32 kernels over bf16-rounded operands, output and operand
        // gradients rounded to bf16 (autograd through explicit casts): bit for bit.
        let round = |t: &Tensor| t.to_kind(Kind::BFloat16).to_kind(Kind::Float);
        let defined = conv_and_gradients(&x, &w, &b, |x, w, b| {
            plain(&round(x), &round(w), &round(b)).to_kind(Kind::BFloat16)
        });
        assert_eq!(emulated[0].kind(), Kind::BFloat16);
        for (e, d) in emulated.iter().zip(&defined) {
            assert_eq!(e.kind(), d.kind());
            assert!(e.equal(d), "{g:?}: differs from its definition");
        }
        // libtorch's own bf16 kernels under autocast: the same up to the order of the fp32
        // sums and one bf16 rounding (relative 2^-8 of the magnitudes involved).
        let native = conv_and_gradients(&x, &w, &b, |x, w, b| {
            rtf_amp::autocast(Device::Cpu, Some(Kind::BFloat16), || plain(x, w, b)).unwrap()
        });
        for (i, (e, n)) in emulated.iter().zip(&native).enumerate() {
            assert_eq!(e.kind(), n.kind(), "tensor {i}");
            let (e, n) = (e.to_kind(Kind::Float), n.to_kind(Kind::Float));
            let scale = n.abs().max().double_value(&[]);
            let worst = (&e - &n).abs().max().double_value(&[]);
            assert!(
                worst <= scale / 64.0,
                "{g:?} tensor {i}: {worst} against {scale}"
            );
        }
    }
}

#[test]
fn emulated_bf16_convolution_takes_bf16_inputs_and_no_bias() {
    let x = Tensor::randn([1, 3, 6, 6], (Kind::Float, Device::Cpu)).to_kind(Kind::BFloat16);
    let w = Tensor::randn([2, 3, 3, 3], (Kind::Float, Device::Cpu)).set_requires_grad(true);
    let g = Geometry {
        stride: 1,
        padding: 0,
        dilation: 1,
        groups: 1,
        transposed: false,
    };
    let y = bf16_emulated_convolution(&x, &w, None, g);
    assert_eq!((y.kind(), y.size()), (Kind::BFloat16, vec![1, 2, 4, 4]));
    y.to_kind(Kind::Float).sum(Kind::Float).backward();
    // The master weight's gradient in its own type; the input needed none.
    assert_eq!(w.grad().kind(), Kind::Float);
    assert!(!x.grad().defined());
}

fn randomise_bn(vs: &nn::VarStore) {
    tch::no_grad(|| {
        for (name, mut t) in vs.variables() {
            if name.contains("running_var") {
                let _ = t.uniform_(0.5, 2.0);
            } else if name.contains("bn") {
                let _ = t.uniform_(-0.5, 0.5);
            }
        }
    });
}

/// A per-channel affine after the unit (a BatchNorm outside it) folds in with the unit's
/// own BatchNorm, before the activation: GELU included (a oneDNN post-op when fused).
#[test]
fn folding_a_following_affine_equals_applying_it() {
    for act in [Act::Identity, Act::Gelu] {
        let vs = nn::VarStore::new(Device::Cpu);
        let spec = ConvSpec::new(3).bias(true);
        let unit = ConvBnAct::new(root(&vs) / "c", Some(root(&vs) / "bn"), 4, 5, spec, act);
        randomise_bn(&vs);
        let x = Tensor::randn([2, 4, 10, 12], (Kind::Float, Device::Cpu));
        let scale = Tensor::rand([5], (Kind::Float, Device::Cpu)) + 0.5;
        let shift = Tensor::randn([5], (Kind::Float, Device::Cpu));
        let (weight, bias) = unit.plain_vars();
        let bn = tch::no_grad(|| {
            x.conv2d(weight, bias, [1], [1], [1], 1)
                .apply_t(unit.bn().unwrap(), false)
        });
        let expected = act.apply(bn * scale.view([1, -1, 1, 1]) + shift.view([1, -1, 1, 1]));
        let folder = Folder::new(&FoldOptions::new(Precision::Fp32));
        let folded = unit.folded_with_affine(&folder, Some((&scale, &shift)));
        let fused = tch::no_grad(|| folded.forward_t(&to_channels_last(&x), false));
        assert!(expected.allclose(&fused, 1e-4, 1e-5, false), "{act:?}");
    }
}

#[test]
fn folding_matches_conv_bn_for_plain_and_transposed() {
    for (spec, act) in [
        (ConvSpec::new(3).bias(true), Act::LeakyRelu(0.2)),
        (ConvSpec::new(3).dilation(2), Act::Relu),
        (ConvSpec::new(3).stride(2), Act::Identity),
        (ConvSpec::new(2).stride(2).transposed(), Act::Relu),
    ] {
        let vs = nn::VarStore::new(Device::Cpu);
        let unit = ConvBnAct::new(root(&vs) / "conv", Some(root(&vs) / "bn"), 6, 5, spec, act);
        randomise_bn(&vs);
        let x = Tensor::randn([2, 6, 12, 16], (Kind::Float, Device::Cpu));
        let plain = tch::no_grad(|| unit.forward_t(&x, false));
        let residual = Tensor::randn(plain.size(), (Kind::Float, Device::Cpu));
        let plain_add = tch::no_grad(|| unit.forward_add(&x, &residual, false));
        let folded = fold(&unit, Precision::Fp32);
        let fused = tch::no_grad(|| folded.forward_t(&to_channels_last(&x), false));
        assert_eq!(plain.size(), fused.size());
        assert!(plain.allclose(&fused, 1e-4, 1e-5, false), "{spec:?}");
        // The trained unit is untouched by its fold and still trains.
        let train = unit.forward_t(&x, true);
        assert!(train.requires_grad());
        // bfloat16: the activation (and the residual add) run inside the convolution.
        let unit = fold(&unit, Precision::Bf16);
        let bf16 = |t: &Tensor| to_channels_last(&t.to_kind(Kind::BFloat16));
        let fused = tch::no_grad(|| unit.forward_t(&bf16(&x), false));
        assert_eq!(fused.kind(), Kind::BFloat16);
        let close = |a: &Tensor, b: &Tensor| a.allclose(&b.to_kind(Kind::Float), 0.05, 0.05, false);
        assert!(close(&plain, &fused), "{spec:?} bf16");
        if !spec.transposed {
            let fused_add = tch::no_grad(|| unit.forward_add(&bf16(&x), &bf16(&residual), false));
            assert!(close(&plain_add, &fused_add), "{spec:?} bf16 + residual");
        }
    }
}

/// Wide 3×3 units fold into a Winograd form (F(4×4, 3×3) from 64 channels, F(2×2, 3×3)
/// from 1024; dilated ones too, through their phase sub-maps), other units into packed
/// oneDNN weights; either way the folded unit computes what conv → BatchNorm → (+ residual)
/// → ReLU does.
#[test]
fn wide_units_fold_into_winograd_forms_with_the_same_values() {
    tch::manual_seed(4);
    for (c, h, w, dilation, form) in [
        (128, 9, 11, 1, Some(36)),
        (1024, 3, 5, 1, Some(16)),
        (64, 6, 7, 1, Some(36)),
        (32, 6, 7, 1, None),
        (128, 10, 13, 2, Some(36)),
        (128, 9, 8, 4, Some(36)),
    ] {
        let vs = nn::VarStore::new(Device::Cpu);
        let spec = ConvSpec::new(3).dilation(dilation);
        let unit = ConvBnAct::new(
            root(&vs) / "conv",
            Some(root(&vs) / "bn"),
            c,
            c,
            spec,
            Act::Relu,
        );
        randomise_bn(&vs);
        let x = Tensor::randn([1, c, h, w], (Kind::Float, Device::Cpu));
        let residual = Tensor::randn([1, c, h, w], (Kind::Float, Device::Cpu));
        let plain = tch::no_grad(|| unit.forward_t(&x, false));
        let plain_add = tch::no_grad(|| unit.forward_add(&x, &residual, false));
        let unit = fold(&unit, Precision::Fp32);
        match (unit.folded_unit().weight_form(), form) {
            (WeightForm::Winograd { positions, .. }, Some(p)) => assert_eq!(positions, p),
            (WeightForm::Packed(_), None) => {}
            (other, _) => panic!("{c} channels folded into {other:?}"),
        }
        let x = to_channels_last(&x);
        let fused = tch::no_grad(|| unit.forward_t(&x, false));
        let fused_add = tch::no_grad(|| unit.forward_add(&x, &to_channels_last(&residual), false));
        for (name, a, b) in [
            ("conv", &plain, &fused),
            ("+ residual", &plain_add, &fused_add),
        ] {
            let scale = a.abs().max().double_value(&[]);
            let worst = (a - b).abs().max().double_value(&[]);
            assert!(
                worst <= 1e-4 * scale,
                "{c} channels, dilation {dilation}, {name}: {worst} of {scale}"
            );
        }
    }
}

/// In bf16 the same wide units fold into the Winograd forms where the bf16 choice says so
/// (float32 transformed weights and bias, bf16 maps in and out) and into bf16 weights for
/// oneDNN where it does not; both compute conv → BatchNorm → (+ residual) → ReLU
/// within bf16's rounding, and the two within bf16's rounding of each other.
#[test]
fn bf16_wide_units_fold_into_winograd_forms_where_chosen() {
    tch::manual_seed(5);
    let bf16 = |t: &Tensor| to_channels_last(&t.to_kind(Kind::BFloat16));
    for (c, h, w, positions) in [(128, 9, 11, 36), (1024, 3, 5, 16)] {
        let vs = nn::VarStore::new(Device::Cpu);
        let conv = root(&vs) / "conv";
        let unit = ConvBnAct::new(
            conv,
            Some(root(&vs) / "bn"),
            c,
            c,
            ConvSpec::new(3),
            Act::Relu,
        );
        randomise_bn(&vs);
        let x = Tensor::randn([1, c, h, w], (Kind::Float, Device::Cpu));
        let residual = Tensor::randn([1, c, h, w], (Kind::Float, Device::Cpu));
        let plain_add = tch::no_grad(|| unit.forward_add(&x, &residual, false));
        let mut outputs = Vec::new();
        for winograd in [true, false] {
            let kernels = InferenceKernels {
                bf16_winograd: winograd,
                ..InferenceKernels::unmeasured()
            };
            let folded = fold_as(&unit, FoldOptions::new(Precision::Bf16).kernels(kernels));
            let f = folded.folded_unit();
            match (f.weight_form(), winograd) {
                (WeightForm::Winograd { positions: p, kind }, true) => {
                    assert_eq!((p, kind), (positions, Kind::Float));
                    assert_eq!(f.bias_kind(), Some(Kind::Float));
                }
                // Packed where oneDNN has bf16 kernels to pack for (not under an AVX2 cap).
                (WeightForm::Packed(_) | WeightForm::Dense(_), false) => {}
                (other, _) => panic!("{c} channels, winograd {winograd}: {other:?}"),
            }
            let y = tch::no_grad(|| folded.forward_add(&bf16(&x), &bf16(&residual), false));
            assert_eq!(
                y.kind(),
                Kind::BFloat16,
                "{c} channels, winograd {winograd}"
            );
            outputs.push(y.to_kind(Kind::Float));
        }
        let scale = plain_add.abs().max().double_value(&[]);
        for (name, a, b) in [
            ("winograd", &plain_add, &outputs[0]),
            ("onednn", &plain_add, &outputs[1]),
            ("winograd against onednn", &outputs[1], &outputs[0]),
        ] {
            let worst = (a - b).abs().max().double_value(&[]);
            assert!(
                worst <= 0.03 * scale,
                "{c} channels, {name}: {worst} of {scale}"
            );
        }
    }
}

#[test]
fn training_on_an_upsampled_input_takes_the_phase_form_with_the_same_values_and_gradients() {
    tch::manual_seed(9);
    let vs = nn::VarStore::new(Device::Cpu);
    let spec = ConvSpec::new(3).bias(true).nearest_upsampled_input();
    let unit = ConvBnAct::new(
        root(&vs) / "c",
        Some(root(&vs) / "bn"),
        5,
        3,
        spec,
        Act::LeakyRelu(0.1),
    );
    let x = Tensor::randn([2, 5, 6, 7], (Kind::Float, Device::Cpu));
    let upstream = Tensor::randn([2, 3, 12, 14], (Kind::Float, Device::Cpu));
    let run = |phases: bool| {
        for mut v in vs.trainable_variables() {
            v.zero_grad();
        }
        let x = x.copy().set_requires_grad(true);
        let y = match phases {
            true => unit.forward_upsampled(&x, true),
            false => {
                let up = x.upsample_nearest2d([12, 14], 2.0, 2.0);
                nn::ModuleT::forward_t(&unit, &up, true)
            }
        };
        (&y * &upstream).sum(Kind::Float).backward();
        let (weight, bias) = unit.plain_vars();
        let bias = bias.expect("built with a bias");
        [
            y.detach(),
            x.grad(),
            weight.grad().copy(),
            bias.grad().copy(),
        ]
    };
    let (phase_form, direct) = (run(true), run(false));
    // Each tensor is compared at the scale of the sum it is (see crate::tolerance): the
    // output and the input gradient at their own magnitude; the weight and bias gradients
    // both sum the same N·H·W terms ∂L/∂z (the weight's times an input patch of unit
    // scale), so both at the weight gradient's magnitude. The bias gradient is zero in
    // exact arithmetic (training-mode BatchNorm removes any per-channel constant): its
    // values are rounding noise of that sum, ~1e-5 against terms reaching ~50, and a fixed
    // atol of 1e-5 passed on AVX-512 kernels and failed on AVX2 ones (issue 33).
    let gradient_scale = crate::tolerance::max_abs(&direct[2]);
    let names = [
        "output",
        "input gradient",
        "weight gradient",
        "bias gradient",
    ];
    let scales = [0.0, 0.0, gradient_scale, gradient_scale];
    for ((name, scale), (p, d)) in names.iter().zip(scales).zip(phase_form.iter().zip(&direct)) {
        if let Err(e) = crate::tolerance::close_at_scale(name, p, d, scale, 1e-4) {
            panic!("phase form against direct: {e}");
        }
    }
    // And the bias gradient is zero at that scale in both forms.
    for bias_gradient in [&phase_form[3], &direct[3]] {
        assert!(crate::tolerance::max_abs(bias_gradient) <= 1e-5 * gradient_scale);
    }
}

/// A training unit over channels-last float32 maps of a shape that gains takes the
/// F(4×4, 3×3) training form, over NCHW maps the direct convolution: the same output (after
/// training-mode BatchNorm) and gradients, each at the scale of the sum it is.
#[test]
fn training_over_channels_last_maps_takes_the_winograd_form_with_the_same_gradients() {
    tch::manual_seed(10);
    let vs = nn::VarStore::new(Device::Cpu);
    let unit = ConvBnAct::new(
        root(&vs) / "c",
        Some(root(&vs) / "bn"),
        128,
        128,
        ConvSpec::new(3),
        // Not a ReLU: outputs within rounding of 0 would flip its mask between the two
        // forms, a full upstream value apiece in the input gradient.
        Act::Identity,
    );
    let x = Tensor::randn([4, 128, 30, 38], (Kind::Float, Device::Cpu));
    assert!(rtf_kernels::winograd::trains_in_f43(
        rtf_kernels::winograd::Forms::All,
        3,
        unit.geometry(),
        128,
        &x.size()
    ));
    let upstream = Tensor::randn([4, 128, 30, 38], (Kind::Float, Device::Cpu));
    let run = |channels_last: bool| {
        for mut v in vs.trainable_variables() {
            v.zero_grad();
        }
        let x = match channels_last {
            true => to_channels_last(&x),
            false => x.copy(),
        }
        .set_requires_grad(true);
        let y = nn::ModuleT::forward_t(&unit, &x, true);
        (&y * &upstream).sum(Kind::Float).backward();
        [y.detach(), x.grad(), unit.plain_vars().0.grad().copy()]
    };
    let (winograd, direct) = (run(true), run(false));
    let names = ["output", "input gradient", "weight gradient"];
    for (name, (w, d)) in names.iter().zip(winograd.iter().zip(&direct)) {
        if let Err(e) = crate::tolerance::close_at_scale(name, w, d, 0.0, 1e-4) {
            panic!("training Winograd form against direct: {e}");
        }
    }
}

/// The Winograd forms a unit trains in are those of the build it belongs to: a unit built
/// with the forms off trains by the direct convolution over the same channels-last maps, and
/// the unit's kernels are its own (a unit of another build beside it keeps its forms).
#[test]
fn a_units_training_forms_are_those_it_was_built_with() {
    use rtf_kernels::winograd::Forms;
    let vs = nn::VarStore::new(Device::Cpu);
    let unit_of = |forms: Forms, name: &str| {
        let options = BuildOptions {
            kernels: UnitKernels {
                winograd: forms,
                ..Default::default()
            },
            uninitialised: false,
        };
        let root = Path::new(vs.root(), &options);
        ConvBnAct::new(
            &root / name,
            None,
            128,
            128,
            ConvSpec::new(3),
            Act::Identity,
        )
    };
    let (all, off) = (unit_of(Forms::All, "all"), unit_of(Forms::Off, "off"));
    let x = to_channels_last(&Tensor::randn([4, 128, 30, 38], (Kind::Float, Device::Cpu)));
    assert!(all.trains_in_winograd(all.plain(), &x, true));
    assert!(!off.trains_in_winograd(off.plain(), &x, true));
    // Never in eval mode, nor over NCHW maps.
    assert!(!all.trains_in_winograd(all.plain(), &x, false));
    assert!(!all.trains_in_winograd(all.plain(), &x.contiguous(), true));
}

#[test]
fn upsampled_input_folds_into_one_phase_convolution() {
    for (act, h, w) in [(Act::LeakyRelu(0.2), 6, 8), (Act::Relu, 5, 7)] {
        let vs = nn::VarStore::new(Device::Cpu);
        let spec = ConvSpec::new(3).bias(true).nearest_upsampled_input();
        let unit = ConvBnAct::new(root(&vs) / "conv", Some(root(&vs) / "bn"), 6, 5, spec, act);
        randomise_bn(&vs);
        let x = Tensor::randn([2, 6, h, w], (Kind::Float, Device::Cpu));
        let upsampled = x.upsample_nearest2d([2 * h, 2 * w], 2.0, 2.0);
        let plain = tch::no_grad(|| unit.forward_t(&upsampled, false));
        assert!(tch::no_grad(|| unit.forward_upsampled(&x, false)).equal(&plain));
        for channels_last in [true, false] {
            let layout = match channels_last {
                true => Layout::ChannelsLast,
                false => Layout::Nchw,
            };
            let folded = fold_as(&unit, FoldOptions::new(Precision::Fp32).layout(layout));
            let input = if channels_last {
                to_channels_last(&x)
            } else {
                x.shallow_clone()
            };
            let fused = tch::no_grad(|| folded.forward_upsampled(&input, false));
            assert_eq!(fused.size(), [2, 5, 2 * h, 2 * w]);
            assert!(fused.is_contiguous());
            assert!(
                plain.allclose(&fused, 1e-4, 1e-5, false),
                "{act:?} {h}x{w} channels-last {channels_last}"
            );
            // The folded unit still takes full-size maps through forward_t.
            let direct = tch::no_grad(|| folded.forward_t(&upsampled, false));
            assert!(plain.allclose(&direct, 1e-4, 1e-5, false));
        }
        // bfloat16 weights and maps: float logits close to the float ones.
        let folded = fold(&unit, Precision::Bf16);
        let input = to_channels_last(&x.to_kind(Kind::BFloat16));
        let fused = tch::no_grad(|| folded.forward_upsampled(&input, false));
        assert_eq!(fused.kind(), Kind::Float);
        assert!(plain.allclose(&fused, 0.05, 0.05, false), "{act:?} bf16");
    }
}

/// Where bf16 is emulated, a bf16 fold keeps float32 weights of bf16 values and computes
/// with float32 kernels over bf16 maps: every entry point (the unit, + residual, then max
/// pooling, on a nearest-upsampled input) gives bf16 maps (float logits for the phase
/// form) within bf16's rounding of the fp32 plain path, as the native bf16 fold does.
#[test]
fn emulated_bf16_folds_compute_in_float_over_bf16_maps() {
    tch::manual_seed(6);
    let opts = (Kind::Float, Device::Cpu);
    let bf16 = |t: &Tensor| to_channels_last(&t.to_kind(Kind::BFloat16));
    let close = |a: &Tensor, b: &Tensor| a.allclose(&b.to_kind(Kind::Float), 0.05, 0.05, false);
    for (spec, act) in [
        (ConvSpec::new(3).bias(true), Act::LeakyRelu(0.2)),
        (ConvSpec::new(1), Act::Relu),
        (ConvSpec::new(2).stride(2).transposed(), Act::Relu),
    ] {
        let vs = nn::VarStore::new(Device::Cpu);
        let unit = ConvBnAct::new(root(&vs) / "conv", Some(root(&vs) / "bn"), 6, 5, spec, act);
        randomise_bn(&vs);
        let x = Tensor::randn([2, 6, 12, 16], opts);
        let plain = tch::no_grad(|| unit.forward_t(&x, false));
        let residual = Tensor::randn(plain.size(), opts);
        let plain_add = tch::no_grad(|| unit.forward_add(&x, &residual, false));
        let pool = |t: &Tensor| t.max_pool2d([2, 2], [2, 2], [0, 0], [1, 1], false);
        let unit = fold_as(&unit, bf16_emulated(true));
        let f = unit.folded_unit();
        assert!(f.float_arith(), "{spec:?}");
        assert!(
            matches!(
                f.weight_form(),
                WeightForm::Packed(Kind::Float) | WeightForm::Dense(Kind::Float)
            ),
            "{spec:?}: {:?}",
            f.weight_form()
        );
        let ys = tch::no_grad(|| unit.forward_t(&bf16(&x), false));
        assert_eq!(ys.kind(), Kind::BFloat16);
        assert!(close(&plain, &ys), "{spec:?}");
        let ys = tch::no_grad(|| unit.forward_add(&bf16(&x), &bf16(&residual), false));
        assert_eq!(ys.kind(), Kind::BFloat16);
        assert!(close(&plain_add, &ys), "{spec:?} + residual");
        let ys = tch::no_grad(|| unit.forward_then_max_pool(&bf16(&x), false, pool));
        assert!(close(&pool(&plain), &ys), "{spec:?} then max pool");
    }
    let vs = nn::VarStore::new(Device::Cpu);
    let unit = ConvBnAct::new(root(&vs) / "c", None, 6, 5, ConvSpec::new(1), Act::Relu);
    assert!(!fold_as(&unit, bf16_emulated(false))
        .folded_unit()
        .float_arith());
    let vs = nn::VarStore::new(Device::Cpu);
    let spec = ConvSpec::new(3).bias(true).nearest_upsampled_input();
    let unit = ConvBnAct::new(root(&vs) / "conv", None, 6, 5, spec, Act::Relu);
    let x = Tensor::randn([1, 6, 5, 7], opts);
    let plain = tch::no_grad(|| unit.forward_upsampled(&x, false));
    let unit = fold_as(&unit, bf16_emulated(true));
    let logits = tch::no_grad(|| unit.forward_upsampled(&bf16(&x), false));
    assert_eq!(logits.kind(), Kind::Float);
    assert!(close(&plain, &logits), "phase form");
}

#[test]
#[should_panic(expected = "plain 3×3 convolution")]
fn upsampled_input_refuses_other_convolutions() {
    let _ = ConvSpec::new(3).dilation(2).nearest_upsampled_input();
}

#[test]
fn pooling_before_the_activation_gives_the_same_values() {
    for act in [Act::LeakyRelu(0.2), Act::Relu] {
        let vs = nn::VarStore::new(Device::Cpu);
        let spec = ConvSpec::new(3).bias(true);
        let unit = ConvBnAct::new(root(&vs) / "conv", Some(root(&vs) / "bn"), 4, 6, spec, act);
        randomise_bn(&vs);
        let x = Tensor::randn([1, 4, 10, 12], (Kind::Float, Device::Cpu));
        let pool = |t: &Tensor| t.max_pool2d_default(2);
        let plain = tch::no_grad(|| pool(&unit.forward_t(&x, false)));
        let unit = fold(&unit, Precision::Fp32);
        let fused = tch::no_grad(|| unit.forward_then_max_pool(&x, false, pool));
        assert!(plain.allclose(&fused, 1e-4, 1e-5, false), "{act:?}");
    }
}

#[test]
fn inference_leaky_relu_equals_definition() {
    let x = Tensor::randn([1000], (Kind::Float, Device::Cpu));
    let expected = x.where_self(&x.gt(0.0), &(&x * 0.2));
    assert!(leaky_relu(&x, 0.2).equal(&expected));
    let y = x.copy();
    let out = leaky_relu_inference(y.shallow_clone(), 0.2);
    assert!(out.equal(&expected));
    assert!(y.equal(&expected), "computed in place");
}

/// The training activations (ATen's leaky_relu, out of place and in place on a unit's fresh
/// output) have the definition's values and gradients: slope·grad below 0, grad above.
#[test]
fn training_leaky_relu_has_the_definitions_values_and_gradients() {
    let x = Tensor::randn([2, 3, 8, 8], (Kind::Float, Device::Cpu)).set_requires_grad(true);
    let expected = x.where_self(&x.gt(0.0), &(&x * 0.1)).detach();
    let grad_expected = (x.gt(0.0).to_kind(Kind::Float) * 0.9 + 0.1).detach();
    let y = leaky_relu(&x, 0.1);
    assert!(y.equal(&expected));
    y.sum(Kind::Float).backward();
    assert!(x.grad().allclose(&grad_expected, 0.0, 1e-7, false));
    // In place on an intermediate (what ConvBnAct does with its BatchNorm output).
    let x2 = x.detach().copy().set_requires_grad(true);
    let fresh = &x2 * 1.0;
    let y2 = Act::LeakyRelu(0.1).apply_fresh(fresh.shallow_clone());
    assert!(y2.equal(&expected));
    assert_eq!(fresh.data_ptr(), y2.data_ptr(), "overwrote its input");
    y2.sum(Kind::Float).backward();
    assert!(x2.grad().allclose(&grad_expected, 0.0, 1e-7, false));
}

#[test]
fn channels_last_keeps_values_and_is_detected() {
    let x = Tensor::randn([2, 3, 4, 5], (Kind::Float, Device::Cpu));
    let cl = to_channels_last(&x);
    assert!(cl.equal(&x));
    assert!(is_channels_last(&cl) && !is_channels_last(&x));
}
