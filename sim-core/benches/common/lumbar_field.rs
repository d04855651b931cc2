//! The synthetic lumbar-like transmission shared by the fluoroscopy finish benches: a
//! soft-tissue background of `ln T` about -3.5, a vertebral column darker by up to 2.5 and two
//! pedicle ovals, with collimator shutters on the outer 4 % of each side, in `f32` (as the GPU
//! renderer reads it back).

/// A `side`^2 transmission and its exposure mask.
pub fn field(side: u32) -> (Vec<f32>, Vec<bool>) {
    let n = side as usize;
    let mut t = Vec::with_capacity(n * n);
    let mut exposed = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            let (x, y) = (i as f64 / n as f64 - 0.5, j as f64 / n as f64 - 0.5);
            let column = (-(x / 0.08).powi(2)).exp() * (1.0 + 0.3 * (y * 40.0).sin());
            let pedicle =
                |cx: f64| (-((x - cx) / 0.03).powi(2) - ((y * 10.0).sin() / 0.4).powi(2)).exp();
            let ln_t = -3.5 - 2.5 * column - 1.0 * (pedicle(-0.1) + pedicle(0.1));
            t.push(ln_t.exp() as f32);
            let edge = 0.46;
            exposed.push(x.abs() < edge && y.abs() < edge);
        }
    }
    (t, exposed)
}
