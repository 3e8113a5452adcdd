//! `WGPU_ADAPTER_NAME` picks the adapter whose name contains it (case-insensitively); a name
//! that matches no adapter is an error listing the adapters, never a fall-back to another one.
//! Its own test binary: it sets the variable for the whole process. Skips with a message when
//! no GPU adapter is found (fails under `CI=true`, where `.ci/run` installs lavapipe).

use augsplat_render::gpu::{GpuContext, GpuError};

#[test]
fn wgpu_adapter_name_picks_an_adapter_or_names_the_ones_there_are() {
    let name = match GpuContext::new() {
        Ok(ctx) => ctx.adapter().name.clone(),
        Err(e) => {
            augsplat_testkit::skip("WGPU_ADAPTER_NAME", &e.to_string());
            return;
        }
    };
    // This binary holds this one test: no other thread reads the environment meanwhile.
    std::env::set_var("WGPU_ADAPTER_NAME", "no-such-gpu-anywhere");
    match GpuContext::new() {
        Ok(ctx) => panic!("fell back to {}", ctx.adapter().name),
        Err(e @ GpuError::NoNamedAdapter { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("no-such-gpu-anywhere"), "{msg}");
            assert!(msg.contains(&name), "the adapters are listed: {msg}");
        }
        Err(e) => panic!("another error: {e}"),
    }
    // Part of the real name, in another case, picks it.
    let part: String = name.chars().take(4).collect::<String>().to_uppercase();
    std::env::set_var("WGPU_ADAPTER_NAME", &part);
    let ctx = GpuContext::new().unwrap_or_else(|e| panic!("{part}: {e}"));
    assert!(ctx.adapter().name.to_uppercase().contains(&part));
    std::env::remove_var("WGPU_ADAPTER_NAME");
}
