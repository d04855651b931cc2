//! The adapter opens headless and a compute shader gives the CPU's answer.

use render_worker::gpu::{context_for_tests, saxpy};

#[test]
fn compute_shader_matches_cpu_bit_for_bit() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    eprintln!("adapter: {:?}", ctx.summary);
    // 1000 elements span 16 workgroups of 64 with a partial last one, so the bounds check in the
    // shader is exercised. Small integers times 3 plus 0.5 are exact in f32.
    let x: Vec<f32> = (0..1000).map(|i| (i as f32) - 500.0).collect();
    let y = saxpy(&ctx, 3.0, &x, 0.5).expect("saxpy on the GPU");
    assert_eq!(y.len(), x.len());
    for (i, (&xi, &yi)) in x.iter().zip(&y).enumerate() {
        assert_eq!(yi.to_bits(), (3.0 * xi + 0.5).to_bits(), "element {i}");
    }
}
