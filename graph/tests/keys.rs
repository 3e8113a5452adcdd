//! Pins the keys (and structural ids) of a tiny fixed pipeline. A key names a computation's
//! outputs in every cache: a refactor that changes one silently orphans every cached result,
//! so these values may only change with a deliberate format change (and `STORE_FORMAT`).

mod common;

use augsplat_graph::store::hex;
use augsplat_graph::{Engine, RunOptions};

/// Covers every ingredient of a key: kind, version, canonical args (with a nested default),
/// an external input, a multi-output reference, seeded and salted repeats, and a list input.
const PIPELINE: &str = r#"(
    nodes: {
        "src": (kind: "Source", args: (value: "ab", count: 2)),
        "app": (kind: "Append", args: (suffix: "!"), inputs: { "a": "src" }),
        "ext": (kind: "Len", inputs: { "a": Path("data") }),
        "len": (kind: "Len", inputs: { "a": "app.len" }),
        "member": (kind: "Seeded", repeat: 2, args: (seed: 7), inputs: { "a": "ext" }),
        "salted": (kind: "Fail", repeat: 2),
        "all": (kind: "Concat", args: (sep: ","), inputs: { "items": "member[*]", "extra": "len" }),
    },
)"#;

/// (instance, key, structural id), in plan order.
const PINNED: &[(&str, &str, &str)] = &[
    (
        "src",
        "a24ec0f6c4e7c02bead59a6ae5e91f22a076a9f49ba2abd698deadf55ef34a51",
        "a4e6f885466ffcca0efb0555924bc99bcae3451d3ec4bfd694be13d562164868",
    ),
    (
        "ext",
        "759c5f1bcdfac6cec5a8f10cd1ae10185e0eaf32adbadd4a26f0f6fd50faaf0e",
        "bc2497b39a35ec0c83273b96f58aab0e2cab89440b1e3aaee4f5a17569fb5228",
    ),
    (
        "salted[0]",
        "5cb47a28969dc70a17ee7bd6c7b9237c087b970bb889f1ad84d608b944ae3f3c",
        "1290b946cc6fe3571c88da23284e264be45bd926518a148587d9e7698f8fca43",
    ),
    (
        "salted[1]",
        "661580a95405c2c956ee8bdc7ba2a491dc811c0d32d8ea9713b02cb2bcc01eb4",
        "6b2efe34b6adf40736f13f0fa27fda658fa36f85174ce2ad21bf9d133902dc9b",
    ),
    (
        "app",
        "b114016112a0311e25ead1e4d67d071cc629ab05c52b246ac5579df31099ae79",
        "b8aeb6def4bf14ff37303249336d25894f1fe3004ca713ba8ea5af2cc2ec53c7",
    ),
    (
        "member[0]",
        "0bf05dec5bd2eb205d887b51768d1f2f59655797e1eaaf960b45247f46ae1eb0",
        "e9e4ea5dd6a2a9ae284abf0daac8363bcc41390357678afa1dfbd49250b61933",
    ),
    (
        "member[1]",
        "34f6619dc0fd4d6cbd29924bf8e3e858ab1b6ab95f2a7314817f8d3c07976124",
        "13744851e2a714d333f7def98c34aff0b2dd673b34adcf4e9dc82c1e89fef7d1",
    ),
    (
        "len",
        "23857251d38d49f5567017f9518f184d83a53dc9657499ccb37da8eddfb12af6",
        "98882dc287e5d22c8b92a3ae0b5a8cab266d65cb9f8cb1d2b2bf7aa02326141b",
    ),
    (
        "all",
        "61a7d9c13041fb5d6fd85fe5c2f0e1cfa33412fa6475d667fd9b8f65b6c030b2",
        "0b29b6122c766192ff7539c7cc99af74cd063610d6874322dc13eea682fe121a",
    ),
];

#[test]
fn keys_of_a_fixed_pipeline_are_pinned() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("data")).unwrap();
    std::fs::write(dir.path().join("data/value.txt"), "external").unwrap();
    let file = dir.path().join("p.ron");
    std::fs::write(&file, PIPELINE).unwrap();
    let engine = Engine::new(
        common::registry(common::Recorder::new()),
        dir.path().join("cache"),
    )
    .unwrap();
    let plan = engine.load(&file, &[]).unwrap();
    let report = engine
        .run(
            &plan,
            &RunOptions {
                jobs: 1,
                ..Default::default()
            },
        )
        .unwrap();
    assert!(report.success());
    let got: Vec<(String, String, String)> = plan
        .instances
        .iter()
        .map(|i| {
            let r = report.results[i.comp].as_ref().unwrap();
            (
                i.name.clone(),
                hex(&r.key.unwrap()),
                hex(&plan.comps[i.comp].sid),
            )
        })
        .collect();
    let want: Vec<(String, String, String)> = PINNED
        .iter()
        .map(|(n, k, s)| (n.to_string(), k.to_string(), s.to_string()))
        .collect();
    assert_eq!(got, want);
}

/// A `resources:` block (Slurm resources) is typed, looked up by node name, then kind, then
/// `default`, and changes no key and no structural id.
#[test]
fn a_resources_block_changes_no_key() {
    use augsplat_graph::resolve::Resources;
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("data")).unwrap();
    std::fs::write(dir.path().join("data/value.txt"), "external").unwrap();
    let engine = Engine::new(
        common::registry(common::Recorder::new()),
        dir.path().join("cache"),
    )
    .unwrap();
    let with = PIPELINE.replacen(
        "(\n    nodes:",
        r#"(
    resources: {
        "default": (cpus: 2),
        "Len": (mem: "1G", time: "00:10:00"),
        "ext": (gpus: 1, partition: "gpu", sbatch: ["--constraint=a100"]),
    },
    nodes:"#,
        1,
    );
    let (plain, res) = (dir.path().join("plain.ron"), dir.path().join("res.ron"));
    std::fs::write(&plain, PIPELINE).unwrap();
    std::fs::write(&res, &with).unwrap();
    let a = engine.load(&plain, &[]).unwrap();
    let b = engine.load(&res, &[]).unwrap();
    let sids = |p: &augsplat_graph::Plan| p.comps.iter().map(|c| c.sid).collect::<Vec<_>>();
    assert_eq!(sids(&a), sids(&b));
    assert!(a.resources.is_empty());
    let comp = |name: &str| {
        b.instances
            .iter()
            .find(|i| i.name == name)
            .map(|i| i.comp)
            .unwrap()
    };
    assert_eq!(
        b.resources_of(comp("ext")),
        Some(&Resources {
            gpus: Some(1),
            partition: Some("gpu".into()),
            sbatch: vec!["--constraint=a100".into()],
            ..Default::default()
        }),
        "the node's name wins"
    );
    assert_eq!(
        b.resources_of(comp("len")).and_then(|r| r.mem.clone()),
        Some("1G".into()),
        "then its kind"
    );
    assert_eq!(b.resources_of(comp("src")).and_then(|r| r.cpus), Some(2));
    let one = RunOptions {
        jobs: 1,
        ..Default::default()
    };
    let ra = engine.run(&a, &one).unwrap();
    let rb = engine.run(&b, &one).unwrap();
    let keys = |r: &augsplat_graph::RunReport| {
        r.results
            .iter()
            .map(|x| x.as_ref().and_then(|x| x.key))
            .collect::<Vec<_>>()
    };
    assert_eq!(keys(&ra), keys(&rb));
    // A typo is an error at the block, with the fields in the hint.
    std::fs::write(&res, with.replace("cpus: 2", "cpu: 2")).unwrap();
    let err = engine.load(&res, &[]).err().unwrap().to_string();
    assert!(err.contains("resources") && err.contains("cpu"), "{err}");
}
