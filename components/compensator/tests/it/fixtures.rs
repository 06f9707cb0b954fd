//! Every PyTorch-exported fixture loads, is recognised, and reproduces PyTorch's output
//! through tract and through the incremental evaluator; incremental == tract on random windows.

use crate::common;
use bowden_compensator::{LoadOptions, Model};
use bowden_interfaces::model::{Architecture, Direction, TcnBlock};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[test]
fn fixtures_reproduce_pytorch_through_tract_and_incremental() {
    for name in common::ALL {
        let m = Model::load(common::fixture(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(
            m.is_incremental(),
            "{name}: not recognised: {:?}",
            m.unrecognised_reason()
        );
        let (x, y_torch) = common::pytorch_io(name);
        let (l, j) = (m.seq_len(), m.joints());
        assert_eq!((l, j, x.len()), (80, 5, 400));
        let y_tract = m.eval_full(&x).unwrap();
        let mut inc = m.incremental().unwrap();
        let x64: Vec<f64> = x.iter().map(|&v| v as f64).collect();
        inc.set_history(&x64[..(l - 1) * j]);
        let mut y_inc = vec![0.0; j];
        inc.eval(&x64[(l - 1) * j..], &mut y_inc);
        for c in 0..j {
            let t = y_torch[c] as f64;
            assert!(
                (y_tract[c] as f64 - t).abs() <= 1e-3,
                "{name} tract q{}: {} vs {t}",
                c + 1,
                y_tract[c]
            );
            assert!(
                (y_inc[c] - t).abs() <= 1e-3,
                "{name} incremental q{}: {} vs {t}",
                c + 1,
                y_inc[c]
            );
        }
        eprintln!(
            "{name}: load check max |inc − tract| = {:.2e} deg, |inc − torch| = {:.2e}, summary {:?}",
            m.load_check_max_abs_diff_deg().unwrap(),
            (0..j).map(|c| (y_inc[c] - y_torch[c] as f64).abs()).fold(0.0, f64::max),
            m.summary().unwrap()
        );
    }
}

#[test]
fn incremental_equals_tract_on_random_windows() {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    for name in common::ALL {
        let m = Model::load_with(
            common::fixture(name),
            &LoadOptions {
                check_windows: 1,
                ..LoadOptions::default()
            },
        )
        .unwrap();
        let (l, j) = (m.seq_len(), m.joints());
        let mut inc = m.incremental().unwrap();
        let mut worst = 0.0f64;
        for w in 0..12 {
            // Some windows start with zero padding (start-up), some are full.
            let zeros = if w % 3 == 0 { rng.random_range(0..l) } else { 0 };
            let win: Vec<f32> = (0..l * j)
                .map(|i| {
                    if i / j < zeros {
                        0.0
                    } else {
                        rng.random_range(-60.0..60.0)
                    }
                })
                .collect();
            let full = m.eval_full(&win).unwrap();
            let w64: Vec<f64> = win.iter().map(|&v| v as f64).collect();
            inc.set_history(&w64[..(l - 1) * j]);
            // Several trials of the last column against one prefix, as in refinement.
            for _ in 0..3 {
                let last: Vec<f32> = (0..j).map(|_| rng.random_range(-60.0..60.0)).collect();
                let mut win2 = win.clone();
                win2[(l - 1) * j..].copy_from_slice(&last);
                let full = m.eval_full(&win2).unwrap();
                let mut y = vec![0.0; j];
                inc.eval(&last.iter().map(|&v| v as f64).collect::<Vec<_>>(), &mut y);
                for c in 0..j {
                    worst = worst.max((y[c] - full[c] as f64).abs());
                }
            }
            let mut y = vec![0.0; j];
            inc.eval(&w64[(l - 1) * j..], &mut y);
            for c in 0..j {
                worst = worst.max((y[c] - full[c] as f64).abs());
            }
        }
        assert!(worst <= 1e-4, "{name}: max |incremental − tract| = {worst:e} deg");
    }
}

#[test]
fn metadata_and_structure_match() {
    for name in common::ALL {
        let m = Model::load(common::fixture(name)).unwrap();
        let md = m.metadata();
        let s = m.summary().unwrap();
        let want_dir = if name.contains("inverse") {
            Direction::Inverse
        } else {
            Direction::Forward
        };
        assert_eq!(md.direction, want_dir, "{name}");
        let arch = match name.split('_').next().unwrap() {
            "tcn" | "tcn-linear2" => Architecture::Tcn,
            "tcn-lstm" | "tcn-lstm-linear2" => Architecture::TcnLstm,
            "fnn" => Architecture::Fnn,
            "lstm" => Architecture::Lstm,
            other => panic!("{other}"),
        };
        assert_eq!(md.architecture, arch, "{name}");
        if arch.has_tcn() {
            let block = if name.contains("linear2") {
                TcnBlock::ReluLinear
            } else {
                TcnBlock::ReluRelu
            };
            assert_eq!(md.tcn_block, Some(block), "{name}");
            assert_eq!((s.convs, s.residual_blocks), (10, 5), "{name}");
            assert_eq!(
                s.blocks_relu_after_second_conv,
                if block == TcnBlock::ReluRelu { 5 } else { 0 }
            );
        }
        if arch == Architecture::Tcn {
            // 5 blocks, k = 3, dilations 1..16: receptive field 1 + 2·2·31 = 125 > L = 80.
            assert_eq!(s.receptive_field, Some(125), "{name}");
            // A trial computes only the newest tap of each of the 10 convs 5→5 (the other two
            // taps read prefix columns and are summed once per window).
            assert_eq!(s.trial_macs, 250, "{name}");
            assert_eq!(s.prefix_macs, 79 * 750, "{name}");
        }
    }
}

#[test]
fn tract_sees_the_same_metadata() {
    // tract exposes the ONNX metadata props as model properties; they must agree with what the
    // loader parsed.
    use tract_onnx::prelude::*;
    for name in common::ALL {
        let m = Model::load(common::fixture(name)).unwrap();
        let tm = tract_onnx::onnx().model_for_path(common::fixture(name)).unwrap();
        let prop = |k: &str| -> Option<String> {
            tm.properties.get(&format!("onnx.metadata_props.{k}")).map(|t| {
                t.to_plain_array_view::<String>()
                    .unwrap()
                    .iter()
                    .next()
                    .unwrap()
                    .clone()
            })
        };
        let md = m.metadata();
        assert_eq!(prop("direction").as_deref(), Some(md.direction.as_str()), "{name}");
        assert_eq!(
            prop("architecture").as_deref(),
            Some(md.architecture.as_str()),
            "{name}"
        );
        assert_eq!(prop("seq_len"), Some(md.seq_len.to_string()), "{name}");
        assert_eq!(prop("joints"), Some(md.joints.to_string()), "{name}");
        assert_eq!(prop("units").as_deref(), Some("deg"), "{name}");
        assert_eq!(prop("tcn_block").as_deref(), md.tcn_block.map(|b| b.as_str()), "{name}");
    }
}
