//! Benchmark: hashing a 1 GiB artifact with blake3 on all cores, against one core and against
//! the raw read bandwidth of the same file (page cache warm; the first pass warms it).
//!
//! ```text
//! cargo run --release -p augsplat-graph --example bench_hash [-- SIZE_MIB [DIR]]
//! ```
//! Compare with `b3sum FILE` when it is installed (the program prints the command).

use std::io::Read;
use std::time::Instant;

fn main() {
    let mib: u64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(1024);
    let dir = std::env::args()
        .nth(2)
        .map(std::path::PathBuf::from)
        .unwrap_or_else(std::env::temp_dir);
    let tmp = tempfile::tempdir_in(&dir).expect("tempdir");
    let path = tmp.path().join("artifact.bin");
    {
        use std::io::Write;
        let mut f = std::io::BufWriter::new(std::fs::File::create(&path).expect("create"));
        let mut state = 0x9E3779B97F4A7C15u64;
        let mut buf = vec![0u8; 1 << 20];
        for _ in 0..mib {
            for chunk in buf.chunks_exact_mut(8) {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                chunk.copy_from_slice(&state.to_le_bytes());
            }
            f.write_all(&buf).expect("write");
        }
    }
    let bytes = (mib << 20) as f64;
    let gib_s = |secs: f64| bytes / secs / (1u64 << 30) as f64;
    let best = |f: &dyn Fn() -> String| -> (f64, String) {
        let mut b = f64::INFINITY;
        let mut out = String::new();
        for _ in 0..3 {
            let t = Instant::now();
            out = f();
            b = b.min(t.elapsed().as_secs_f64());
        }
        (b, out)
    };
    let (t_read, _) = best(&|| {
        let mut f = std::fs::File::open(&path).expect("open");
        let mut buf = vec![0u8; 1 << 20];
        let mut acc = 0u64;
        loop {
            let n = f.read(&mut buf).expect("read");
            if n == 0 {
                break;
            }
            acc = acc.wrapping_add(buf[n - 1] as u64);
        }
        acc.to_string()
    });
    let (t_one, h1) = best(&|| {
        let mut h = blake3::Hasher::new();
        h.update_reader(std::fs::File::open(&path).expect("open"))
            .expect("hash");
        h.finalize().to_hex().to_string()
    });
    let (t_mmap1, h2) = best(&|| {
        let mut h = blake3::Hasher::new();
        h.update_mmap(&path).expect("hash");
        h.finalize().to_hex().to_string()
    });
    let (t_all, h3) = best(&|| augsplat_graph::store::hash_file(&path).expect("hash"));
    assert!(h1 == h2 && h2 == h3);
    let threads = rayon::current_num_threads();
    println!("file: {} MiB at {}", mib, path.display());
    println!(
        "raw read (1 MiB buffers, 1 thread):      {:.3} s  {:.2} GiB/s",
        t_read,
        gib_s(t_read)
    );
    println!(
        "blake3, read + hash, 1 thread:           {:.3} s  {:.2} GiB/s",
        t_one,
        gib_s(t_one)
    );
    println!(
        "blake3, mmap, 1 thread:                  {:.3} s  {:.2} GiB/s",
        t_mmap1,
        gib_s(t_mmap1)
    );
    println!(
        "blake3, mmap + rayon, {threads} threads (engine): {:.3} s  {:.2} GiB/s",
        t_all,
        gib_s(t_all)
    );
    match std::process::Command::new("b3sum").arg(&path).output() {
        Ok(o) if o.status.success() => {
            let t = Instant::now();
            let o = std::process::Command::new("b3sum")
                .arg(&path)
                .output()
                .expect("b3sum");
            let secs = t.elapsed().as_secs_f64();
            let same = String::from_utf8_lossy(&o.stdout).starts_with(&h3);
            println!(
                "b3sum {}:  {:.3} s  {:.2} GiB/s (same hash: {same})",
                path.display(),
                secs,
                gib_s(secs)
            );
        }
        _ => println!("b3sum is not installed; compare against the raw read line above"),
    }
}
