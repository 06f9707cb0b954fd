//! Adam (Kingma & Ba), as `torch.optim.Adam` with its defaults (β = 0.9, 0.999, ε = 1e-8,
//! no weight decay) — equivalently candle's `AdamW` with weight decay 0 — over a flat
//! parameter vector.

use crate::kernels::AVec;

#[derive(Debug, Clone)]
pub struct Adam {
    pub lr: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    m: AVec<f32>,
    v: AVec<f32>,
    t: u64,
}

impl Adam {
    pub fn new(n: usize, lr: f64) -> Self {
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            m: AVec::from_elem(0.0, n),
            v: AVec::from_elem(0.0, n),
            t: 0,
        }
    }

    /// Steps taken so far.
    pub fn steps(&self) -> u64 {
        self.t
    }

    pub fn step(&mut self, params: &mut [f32], grad: &[f32]) {
        let (k, m, v) = self.begin();
        k.apply(params, grad, m, v);
    }

    /// Starts one step: its coefficients and the moment buffers, which the caller may split
    /// into ranges and [`AdamStep::apply`] on different threads (every element is updated
    /// on its own, so any split gives the bits of [`Adam::step`]).
    pub fn begin(&mut self) -> (AdamStep, &mut [f32], &mut [f32]) {
        self.t += 1;
        let bc1 = 1.0 - self.beta1.powi(self.t as i32);
        let bc2 = 1.0 - self.beta2.powi(self.t as i32);
        let k = AdamStep {
            step: (self.lr / bc1) as f32,
            inv_sqrt_bc2: (1.0 / bc2.sqrt()) as f32,
            b1: self.beta1 as f32,
            b2: self.beta2 as f32,
            eps: self.eps as f32,
        };
        (k, &mut self.m, &mut self.v)
    }
}

/// The coefficients of one Adam step (see [`Adam::begin`]).
#[derive(Debug, Clone, Copy)]
pub struct AdamStep {
    step: f32,
    inv_sqrt_bc2: f32,
    b1: f32,
    b2: f32,
    eps: f32,
}

impl AdamStep {
    /// Updates `params` from `grad` and the moments `m`, `v` of the same elements. Written
    /// over zipped slices so it vectorises (no bounds checks); the operations per element
    /// are those of the scalar loop it replaced, in the same order: the same bits.
    pub fn apply(&self, params: &mut [f32], grad: &[f32], m: &mut [f32], v: &mut [f32]) {
        let AdamStep {
            step,
            inv_sqrt_bc2,
            b1,
            b2,
            eps,
        } = *self;
        for (((p, g), mi), vi) in params.iter_mut().zip(grad).zip(m.iter_mut()).zip(v.iter_mut()) {
            let g = *g;
            let mn = b1 * *mi + (1.0 - b1) * g;
            let vn = b2 * *vi + (1.0 - b2) * g * g;
            *mi = mn;
            *vi = vn;
            *p -= step * mn / (vn.sqrt() * inv_sqrt_bc2 + eps);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_step_moves_each_parameter_by_lr() {
        // With bias correction the first Adam step is lr · sign(g) (up to ε).
        let mut a = Adam::new(3, 1e-3);
        let mut p = vec![1.0f32, -2.0, 0.5];
        a.step(&mut p, &[0.3, -7.0, 1e-3]);
        assert!((p[0] - (1.0 - 1e-3)).abs() < 1e-6);
        assert!((p[1] - (-2.0 + 1e-3)).abs() < 1e-6);
        assert!((p[2] - (0.5 - 1e-3)).abs() < 1e-5);
    }

    #[test]
    fn minimises_a_quadratic() {
        let mut a = Adam::new(2, 0.05);
        let mut p = vec![3.0f32, -4.0];
        for _ in 0..2000 {
            let g = vec![2.0 * p[0], 2.0 * (p[1] + 1.0)];
            a.step(&mut p, &g);
        }
        assert!(p[0].abs() < 1e-2 && (p[1] + 1.0).abs() < 1e-2, "{p:?}");
    }
}
