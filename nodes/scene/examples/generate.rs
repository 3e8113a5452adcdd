//! Generates the default synthetic scene into a folder and prints the time it took:
//! `cargo run --release -p augsplat-scene --example generate -- OUT [views] [width] [height]`.

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(out) = args.get(1) else {
        eprintln!("usage: generate OUT [views] [width] [height] [forward]");
        std::process::exit(2);
    };
    let mut p = augsplat_scene::synthetic::SyntheticParams::default();
    if let Some(v) = args.get(2).and_then(|s| s.parse().ok()) {
        p.views = v;
    }
    if let Some(v) = args.get(3).and_then(|s| s.parse().ok()) {
        p.width = v;
    }
    if let Some(v) = args.get(4).and_then(|s| s.parse().ok()) {
        p.height = v;
    }
    if args.get(5).is_some_and(|s| s == "forward") {
        p.layout = augsplat_scene::synthetic::Layout::Forward;
    }
    let t = std::time::Instant::now();
    match augsplat_scene::synthetic::generate(&p, std::path::Path::new(out)) {
        Ok(s) => println!(
            "{} views, near {:.3} far {:.3}, {:.2} s",
            s.views.len(),
            s.near,
            s.far,
            t.elapsed().as_secs_f64()
        ),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
