//! LPIPS: published distances, identity, errors, an independent f64 reference, thread-count
//! independence and weight loading/lookup. Tests needing the shared data skip with a message
//! when it is absent.

use augsplat_core::image::read_rgb;
use augsplat_core::ImageF32;
use augsplat_metrics::lpips::{
    bundled_dir, bundled_weights, find_weights, locate_weights, Backbone, Lpips, WeightSource,
};
use std::path::{Path, PathBuf};

fn lpips_dir() -> Option<PathBuf> {
    augsplat_testkit::data::shared_data("LPIPS", "lpips/lpips_alex_v0.1.safetensors")
        .map(|d| d.join("lpips"))
}

fn model(d: &Path, b: Backbone) -> Lpips {
    Lpips::load(&d.join(b.file_name())).unwrap()
}

fn noise(w: u32, h: u32, seed: u64) -> ImageF32 {
    let mut rng = augsplat_core::Rng::new(seed);
    let mut im = ImageF32::new(w, h, 3);
    for (i, v) in im.data.iter_mut().enumerate() {
        let x = ((i / 3) as u32 % w) as f32;
        let y = ((i / 3) as u32 / w) as f32;
        *v = (0.5 + 0.3 * (x * 0.3 + y * 0.2 + seed as f32).sin() + 0.2 * (rng.next_f32() - 0.5))
            .clamp(0.0, 1.0);
    }
    im
}

#[test]
fn published_distances() {
    let Some(d) = lpips_dir() else { return };
    let alex = model(&d, Backbone::Alex);
    assert_eq!(alex.backbone(), Backbone::Alex);
    let r = read_rgb(&d.join("ex_ref.png")).unwrap();
    let p0 = read_rgb(&d.join("ex_p0.png")).unwrap();
    let p1 = read_rgb(&d.join("ex_p1.png")).unwrap();
    let d0 = alex.distance(&r, &p0).unwrap();
    let d1 = alex.distance(&r, &p1).unwrap();
    // Published with three decimals.
    assert!((d0 - 0.722).abs() < 5e-4, "{d0}");
    assert!((d1 - 0.138).abs() < 5e-4, "{d1}");
    let vgg = model(&d, Backbone::Vgg);
    assert_eq!(vgg.backbone(), Backbone::Vgg);
    let apple = read_rgb(&d.join("apple.png")).unwrap();
    let pear = read_rgb(&d.join("pear.png")).unwrap();
    let v = vgg.distance(&apple, &pear).unwrap();
    assert!((v - 0.6571019887924194).abs() < 1e-4, "{v}");
    // Symmetric up to rounding.
    let v2 = vgg.distance(&pear, &apple).unwrap();
    assert!((v - v2).abs() < 1e-6);
}

#[test]
fn identity_is_zero_and_errors_are_clear() {
    let Some(d) = lpips_dir() else { return };
    for b in [Backbone::Alex, Backbone::Vgg] {
        let m = model(&d, b);
        let a = noise(64, 48, 1);
        assert_eq!(m.distance(&a, &a).unwrap(), 0.0, "{b}");
        let other = noise(48, 64, 1);
        let e = m.distance(&a, &other).unwrap_err().to_string();
        assert!(e.contains("sizes differ"), "{e}");
        let mut nan = a.clone();
        nan.set(5, 7, 2, f32::NAN);
        let e = m.distance(&a, &nan).unwrap_err().to_string();
        assert!(e.contains("non-finite") && e.contains("x 5, y 7"), "{e}");
        let mut inf = a.clone();
        inf.set(0, 0, 0, f32::INFINITY);
        assert!(m.distance(&inf, &a).is_err());
        let tiny = noise(12, 12, 2);
        let e = m.distance(&tiny, &tiny).unwrap_err().to_string();
        assert!(e.contains("too small"), "{e}");
        let grey = ImageF32::new(64, 48, 1);
        let e = m.distance(&grey, &grey).unwrap_err().to_string();
        assert!(e.contains("RGB"), "{e}");
    }
}

// ---------- independent f64 reference ----------

struct RefNet {
    /// (weights OIHW, bias, out, in, k, stride, pad) or a pool (k, s) or a tap.
    steps: Vec<RefStep>,
    heads: Vec<Vec<f64>>,
}

enum RefStep {
    Conv(Vec<f64>, Vec<f64>, usize, usize, usize, usize, usize),
    Pool(usize, usize),
    Tap,
}

/// (features index, out channels, kernel, stride, pad)
type ConvSpec = (usize, usize, usize, usize, usize);

fn ref_net(path: &Path, backbone: Backbone) -> RefNet {
    let bytes = std::fs::read(path).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let get = |n: &str| -> Vec<f64> {
        st.tensor(n)
            .unwrap()
            .data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f64)
            .collect()
    };
    // torchvision: AlexNet features and VGG16 features ("M" = 2×2 max-pool).
    let (convs, plan): (Vec<ConvSpec>, &str) = match backbone {
        Backbone::Alex => (
            vec![
                (0, 64, 11, 4, 2),
                (3, 192, 5, 1, 2),
                (6, 384, 3, 1, 1),
                (8, 256, 3, 1, 1),
                (10, 256, 3, 1, 1),
            ],
            "cTPcTPcTcTcT",
        ),
        Backbone::Vgg => (
            [0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28]
                .iter()
                .zip([
                    64, 64, 128, 128, 256, 256, 256, 512, 512, 512, 512, 512, 512,
                ])
                .map(|(&i, o)| (i, o, 3, 1, 1))
                .collect(),
            "ccTPccTPcccTPcccTPcccT",
        ),
    };
    let pool = if backbone == Backbone::Alex {
        (3, 2)
    } else {
        (2, 2)
    };
    let mut steps = Vec::new();
    let mut ci = 3;
    let mut convs = convs.into_iter();
    for ch in plan.chars() {
        match ch {
            'c' => {
                let (i, o, k, s, p) = convs.next().unwrap();
                steps.push(RefStep::Conv(
                    get(&format!("features.{i}.weight")),
                    get(&format!("features.{i}.bias")),
                    o,
                    ci,
                    k,
                    s,
                    p,
                ));
                ci = o;
            }
            'P' => steps.push(RefStep::Pool(pool.0, pool.1)),
            _ => steps.push(RefStep::Tap),
        }
    }
    let heads = (0..5)
        .map(|i| get(&format!("lin{i}.model.1.weight")))
        .collect();
    RefNet { steps, heads }
}

/// (C, H, W, data)
type T64 = (usize, usize, usize, Vec<f64>);

fn ref_features(net: &RefNet, img: &ImageF32) -> Vec<T64> {
    let (w, h) = (img.width as usize, img.height as usize);
    let shift = [-0.030, -0.088, -0.188];
    let scale = [0.458, 0.448, 0.450];
    let mut x: T64 = (3, h, w, vec![0.0; 3 * h * w]);
    for c in 0..3 {
        for p in 0..h * w {
            x.3[c * h * w + p] = (img.data[p * 3 + c] as f64 * 2.0 - 1.0 - shift[c]) / scale[c];
        }
    }
    let mut taps = Vec::new();
    for step in &net.steps {
        match step {
            RefStep::Conv(wt, b, o, ci, k, s, p) => {
                let (_, ih, iw, ref inp) = x;
                let oh = (ih + 2 * p - k) / s + 1;
                let ow = (iw + 2 * p - k) / s + 1;
                let mut out = vec![0.0; o * oh * ow];
                for oc in 0..*o {
                    for oy in 0..oh {
                        for ox in 0..ow {
                            let mut acc = b[oc];
                            for c in 0..*ci {
                                for ky in 0..*k {
                                    let iy = (oy * s + ky) as isize - *p as isize;
                                    if iy < 0 || iy >= ih as isize {
                                        continue;
                                    }
                                    for kx in 0..*k {
                                        let ix = (ox * s + kx) as isize - *p as isize;
                                        if ix < 0 || ix >= iw as isize {
                                            continue;
                                        }
                                        acc += wt[((oc * ci + c) * k + ky) * k + kx]
                                            * inp[(c * ih + iy as usize) * iw + ix as usize];
                                    }
                                }
                            }
                            out[(oc * oh + oy) * ow + ox] = acc.max(0.0);
                        }
                    }
                }
                x = (*o, oh, ow, out);
            }
            RefStep::Pool(k, s) => {
                let (c, ih, iw, ref inp) = x;
                let oh = (ih - k) / s + 1;
                let ow = (iw - k) / s + 1;
                let mut out = vec![f64::NEG_INFINITY; c * oh * ow];
                for ch in 0..c {
                    for oy in 0..oh {
                        for ox in 0..ow {
                            for ky in 0..*k {
                                for kx in 0..*k {
                                    let v = inp[(ch * ih + oy * s + ky) * iw + ox * s + kx];
                                    let o = &mut out[(ch * oh + oy) * ow + ox];
                                    *o = o.max(v);
                                }
                            }
                        }
                    }
                }
                x = (c, oh, ow, out);
            }
            RefStep::Tap => taps.push(x.clone()),
        }
    }
    taps
}

fn ref_distance(net: &RefNet, a: &ImageF32, b: &ImageF32) -> f64 {
    let (fa, fb) = (ref_features(net, a), ref_features(net, b));
    let mut total = 0.0;
    for ((ta, tb), head) in fa.iter().zip(&fb).zip(&net.heads) {
        let (c, h, w) = (ta.0, ta.1, ta.2);
        let mut s = 0.0;
        for p in 0..h * w {
            let na: f64 = (0..c)
                .map(|k| ta.3[k * h * w + p].powi(2))
                .sum::<f64>()
                .sqrt()
                + 1e-10;
            let nb: f64 = (0..c)
                .map(|k| tb.3[k * h * w + p].powi(2))
                .sum::<f64>()
                .sqrt()
                + 1e-10;
            for (k, hk) in head.iter().enumerate() {
                let d = ta.3[k * h * w + p] / na - tb.3[k * h * w + p] / nb;
                s += hk * d * d;
            }
        }
        total += s / (h * w) as f64;
    }
    total
}

#[test]
fn matches_f64_reference() {
    let Some(d) = lpips_dir() else { return };
    for (b, w, h) in [(Backbone::Alex, 67, 45), (Backbone::Vgg, 19, 17)] {
        let m = model(&d, b);
        let r = ref_net(&d.join(b.file_name()), b);
        let x = noise(w, h, 10);
        let mut y = noise(w, h, 11);
        y.data.iter_mut().for_each(|v| *v = 1.0 - *v * *v);
        let fast = m.distance(&x, &y).unwrap();
        let reference = ref_distance(&r, &x, &y);
        eprintln!("{b}: {fast} vs f64 {reference}");
        assert!(
            reference > 0.02 && (fast - reference).abs() < 1e-5 * reference,
            "{b}: {fast} vs {reference}"
        );
    }
}

#[test]
fn thread_count_does_not_change_bits() {
    let Some(d) = lpips_dir() else { return };
    let m = model(&d, Backbone::Alex);
    let (x, y) = (noise(203, 141, 3), noise(203, 141, 4));
    let run = |n| augsplat_testkit::with_threads(n, || m.distance(&x, &y).unwrap());
    assert_eq!(run(1).to_bits(), run(2).to_bits());
    assert_eq!(run(2).to_bits(), run(3).to_bits());
}

#[test]
fn bad_weight_files_are_rejected() {
    let Some(d) = lpips_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let junk = tmp.path().join("junk.safetensors");
    std::fs::write(&junk, b"not a safetensors file").unwrap();
    let e = Lpips::load(&junk).unwrap_err().to_string();
    assert!(e.contains("junk.safetensors"), "{e}");
    let e = Lpips::load(&tmp.path().join("missing.safetensors"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.safetensors"), "{e}");
    // The alex file without its last head, and with a wrongly shaped head.
    let bytes = std::fs::read(d.join(Backbone::Alex.file_name())).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let keep: Vec<(String, safetensors::tensor::TensorView<'_>)> = st
        .tensors()
        .into_iter()
        .filter(|(n, _)| n != "lin4.model.1.weight")
        .collect();
    let cut = safetensors::tensor::serialize(keep.clone(), None).unwrap();
    let e = Lpips::from_safetensors(&cut).unwrap_err();
    assert!(e.contains("lin4.model.1.weight"), "{e}");
    let head = vec![0u8; 4 * 255];
    let mut bad = keep;
    bad.push((
        "lin4.model.1.weight".into(),
        safetensors::tensor::TensorView::new(safetensors::Dtype::F32, vec![1, 255, 1, 1], &head)
            .unwrap(),
    ));
    let e =
        Lpips::from_safetensors(&safetensors::tensor::serialize(bad, None).unwrap()).unwrap_err();
    assert!(
        e.contains("lin4.model.1.weight") && e.contains("[1, 256, 1, 1]"),
        "{e}"
    );
}

/// All environment manipulation lives in this one test (the environment is process-wide).
#[test]
fn weight_lookup_order() {
    let tmp = tempfile::tempdir().unwrap();
    let (explicit, env_dir, xdg) = (
        tmp.path().join("e"),
        tmp.path().join("v"),
        tmp.path().join("x"),
    );
    for dir in [&explicit, &env_dir, &xdg.join("augsplat/lpips")] {
        std::fs::create_dir_all(dir).unwrap();
        std::fs::write(dir.join(Backbone::Alex.file_name()), b"x").unwrap();
    }
    // Nothing installed: the shipped AlexNet weights; no VGG16.
    std::env::set_var("XDG_DATA_HOME", tmp.path().join("empty"));
    std::env::remove_var("AUGSPLAT_LPIPS_WEIGHTS");
    let shipped = bundled_dir().join(Backbone::Alex.file_name());
    assert_eq!(find_weights(None, Backbone::Alex), Some(shipped.clone()));
    assert_eq!(
        locate_weights(Backbone::Alex),
        Some((shipped, WeightSource::Bundled))
    );
    assert_eq!(find_weights(None, Backbone::Vgg), None);
    std::env::set_var("XDG_DATA_HOME", &xdg);
    let xdg_file = xdg.join("augsplat/lpips").join(Backbone::Alex.file_name());
    assert_eq!(
        locate_weights(Backbone::Alex),
        Some((xdg_file.clone(), WeightSource::DefaultDir))
    );
    assert_eq!(find_weights(None, Backbone::Alex), Some(xdg_file.clone()));
    assert_eq!(find_weights(None, Backbone::Vgg), None);
    std::env::set_var("AUGSPLAT_LPIPS_WEIGHTS", &env_dir);
    assert_eq!(
        find_weights(None, Backbone::Alex),
        Some(env_dir.join(Backbone::Alex.file_name()))
    );
    // A variable naming a folder without the file falls through to the default location.
    std::env::set_var("AUGSPLAT_LPIPS_WEIGHTS", tmp.path());
    assert_eq!(find_weights(None, Backbone::Alex), Some(xdg_file));
    let file = explicit.join(Backbone::Alex.file_name());
    std::env::set_var("AUGSPLAT_LPIPS_WEIGHTS", &file);
    assert_eq!(find_weights(None, Backbone::Vgg), Some(file.clone()));
    assert_eq!(
        find_weights(Some(&explicit), Backbone::Alex),
        Some(file.clone())
    );
    assert_eq!(find_weights(Some(&file), Backbone::Alex), Some(file));
    // An explicit path that holds nothing is not silently replaced by another file.
    assert_eq!(
        find_weights(Some(&tmp.path().join("nope")), Backbone::Alex),
        None
    );
    std::env::remove_var("AUGSPLAT_LPIPS_WEIGHTS");
    std::env::remove_var("XDG_DATA_HOME");
}

/// The shipped AlexNet weights load (float16, upcast) without any shared data; they are not
/// the identity (a metric of zero everywhere) and give nothing for VGG16.
#[test]
fn shipped_weights_load() {
    let f = bundled_weights(Backbone::Alex).expect("nodes/metrics/weights holds the alex file");
    let bytes = std::fs::read(&f).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    assert_eq!(st.names().len(), 15);
    for (name, t) in st.tensors() {
        assert_eq!(t.dtype(), safetensors::Dtype::F16, "{name}");
    }
    let m = Lpips::from_safetensors(&bytes).unwrap();
    assert_eq!(m.backbone(), Backbone::Alex);
    let (a, b) = (noise(64, 64, 1), noise(64, 64, 2));
    assert_eq!(m.distance(&a, &a).unwrap(), 0.0);
    let d = m.distance(&a, &b).unwrap();
    assert!(d > 0.01 && d < 1.0, "{d}");
    assert_eq!(bundled_weights(Backbone::Vgg), None);
    assert!(bundled_dir().join("LICENSE.md").is_file());
}

/// Images too small for the backbone have no LPIPS (nor average error) in a measurement, as
/// without weights, instead of failing the node that measures them.
#[test]
fn images_too_small_for_the_backbone_have_no_lpips() {
    let f = bundled_weights(Backbone::Alex).expect("nodes/metrics/weights holds the alex file");
    let m = Lpips::load(&f).unwrap();
    assert!(!m.accepts(32, 24) && m.accepts(64, 64));
    let (a, b) = (noise(32, 24, 1), noise(32, 24, 2));
    let small = augsplat_metrics::measure::measure(&a, &b, Some(&m)).unwrap();
    assert_eq!((small.lpips, small.avg_error), (None, None));
    assert!(small.psnr.is_finite());
    let (a, b) = (noise(64, 64, 1), noise(64, 64, 2));
    let big = augsplat_metrics::measure::measure(&a, &b, Some(&m)).unwrap();
    assert!(big.lpips.is_some() && big.avg_error.is_some());
}
