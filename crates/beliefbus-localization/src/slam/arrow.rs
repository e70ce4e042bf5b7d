//! Implicit sampling of one step's pose and every feature it sees, jointly
//! (paper 003 §4.2: "the extension to observing multiple features
//! simultaneously is straightforward"):
//!
//! ```text
//! F(x, θ_1..θ_p) = ½‖x − f‖²_{Σ₁⁻¹} + Σ_b [ Σ_{z ∈ returns of b} ½‖z − h(x, θ_b)‖²_{Σ₂⁻¹} + F_past,b(θ_b) ]
//! ```
//!
//! F_past,b holds feature b's earlier sightings ([`super::refined_map`]);
//! a new feature has none (flat prior). Given the pose the features are
//! independent, so the Hessian is an arrow: 2×2 blocks D_b on the features,
//! coupled only through 3×2 blocks B_b to the pose. Ordering the features
//! first, its Cholesky factor is
//!
//! ```text
//! L = [ L_D      0  ]    L_b L_bᵀ = D_b,   C_b = B_b L_b⁻ᵀ,
//!     [ C      L_S  ]    L_S L_Sᵀ = S = H_xx − Σ_b B_b D_b⁻¹ B_bᵀ
//! ```
//!
//! so a Newton step, the linear map v = μ + L⁻ᵀξ and log det L cost O(p),
//! with no allocation once the buffers have grown to the largest p.

use super::assoc::RangeBearing;
use super::refined_map::RefinedLandmark;
use crate::geometry::{wrap_angle, Point, Pose};
use crate::laser::{add_term, Curvature, LaserNoise, Observation};
use nalgebra::{Matrix2, Matrix3, Matrix3x2, Vector2, Vector3};

/// One feature of the step: its earlier sightings (None: new) and the
/// index range of its returns in [`Arrow::returns`].
#[derive(Clone, Copy, Debug)]
pub struct Block {
    pub past: Option<RefinedLandmark>,
    pub start: usize,
    pub len: usize,
}

/// F and its derivatives at a point, blockwise.
#[derive(Clone, Debug, Default)]
struct Derivs {
    gx: Vector3<f64>,
    hxx: Matrix3<f64>,
    gt: Vec<Vector2<f64>>,
    ht: Vec<Matrix2<f64>>,
    hxt: Vec<Matrix3x2<f64>>,
}

/// The factor of H: L_b per block, C_b, L_S, log det L.
#[derive(Clone, Debug, Default)]
struct Factor {
    lb: Vec<Matrix2<f64>>,
    c: Vec<Matrix3x2<f64>>,
    ls: Matrix3<f64>,
    log_det: f64,
}

/// The step's joint objective and its work buffers.
#[derive(Clone, Debug, Default)]
pub struct Arrow {
    pub f: Pose,
    pub prec: Matrix3<f64>,
    pub laser: LaserNoise,
    pub blocks: Vec<Block>,
    pub returns: Vec<RangeBearing>,
    /// Current point: pose and features.
    pub x: Pose,
    pub th: Vec<Point>,
    d: Derivs,
    dn: Derivs,
    fac: Factor,
    th_try: Vec<Point>,
    step_t: Vec<Vector2<f64>>,
}

/// A Newton minimum's summary.
#[derive(Clone, Copy, Debug)]
pub struct ArrowMinimum {
    pub phi: f64,
    pub log_det_l: f64,
    pub iters: usize,
}

impl Derivs {
    fn reset(&mut self, p: usize) {
        self.gx = Vector3::zeros();
        self.hxx = Matrix3::zeros();
        self.gt.clear();
        self.gt.resize(p, Vector2::zeros());
        self.ht.clear();
        self.ht.resize(p, Matrix2::zeros());
        self.hxt.clear();
        self.hxt.resize(p, Matrix3x2::zeros());
    }
}

impl Arrow {
    /// Start a step: prediction f, Σ₁⁻¹, no blocks.
    pub fn begin(&mut self, f: Pose, prec: Matrix3<f64>, laser: LaserNoise) {
        self.f = f;
        self.prec = prec;
        self.laser = laser;
        self.x = f;
        self.blocks.clear();
        self.returns.clear();
        self.th.clear();
    }

    /// Add a feature with its returns and its start value.
    pub fn push(&mut self, past: Option<RefinedLandmark>, zs: &[RangeBearing], start: Point) {
        self.blocks.push(Block {
            past,
            start: self.returns.len(),
            len: zs.len(),
        });
        self.returns.extend_from_slice(zs);
        self.th.push(start);
    }

    /// Number of features.
    pub fn len(&self) -> usize {
        self.blocks.len()
    }

    /// Whether the step has no feature.
    pub fn is_empty(&self) -> bool {
        self.blocks.is_empty()
    }

    fn eval_into(&self, x: &Pose, th: &[Point], curv: Curvature, d: &mut Derivs) -> f64 {
        d.reset(self.blocks.len());
        let mut dx = x - self.f;
        dx[2] = wrap_angle(dx[2]);
        let pd = self.prec * dx;
        let mut val = 0.5 * dx.dot(&pd);
        d.gx += pd;
        d.hxx += self.prec;
        for (b, blk) in self.blocks.iter().enumerate() {
            let (mut g3, mut h3) = (Vector3::zeros(), Matrix3::zeros());
            for z in &self.returns[blk.start..blk.start + blk.len] {
                let o = Observation {
                    range: z.range,
                    bearing: z.bearing,
                    landmark: 0,
                };
                val += add_term(x, th[b], &o, &self.laser, curv, &mut g3, &mut h3);
            }
            // The term depends on x₁₂ − θ_b (see super::joint).
            d.gx += g3;
            d.hxx += h3;
            d.gt[b] = Vector2::new(-g3[0], -g3[1]);
            d.ht[b] = Matrix2::new(h3[(0, 0)], h3[(0, 1)], h3[(1, 0)], h3[(1, 1)]);
            d.hxt[b] = Matrix3x2::from_fn(|i, a| -h3[(i, a)]);
            if let Some(lm) = &blk.past {
                val += lm.add_past(th[b], &self.laser, curv, &mut d.gt[b], &mut d.ht[b]);
            }
        }
        val
    }

    /// F at (x, θ).
    pub fn value(&self, x: &Pose, th: &[Point]) -> f64 {
        let mut d = Derivs::default();
        self.eval_into(x, th, Curvature::GaussNewton, &mut d)
    }

    /// F with its gradient and Hessian at (x, θ), as dense matrices over
    /// (x₁, x₂, β, θ_1, …, θ_p) (for tests).
    pub fn dense(&self, x: &Pose, th: &[Point]) -> (f64, Vec<f64>, Vec<Vec<f64>>) {
        let mut d = Derivs::default();
        let v = self.eval_into(x, th, Curvature::Exact, &mut d);
        let n = 3 + 2 * th.len();
        let mut g = vec![0.0; n];
        let mut h = vec![vec![0.0; n]; n];
        for i in 0..3 {
            g[i] = d.gx[i];
            for j in 0..3 {
                h[i][j] = d.hxx[(i, j)];
            }
        }
        for b in 0..th.len() {
            for a in 0..2 {
                g[3 + 2 * b + a] = d.gt[b][a];
                for c in 0..2 {
                    h[3 + 2 * b + a][3 + 2 * b + c] = d.ht[b][(a, c)];
                }
                for i in 0..3 {
                    h[i][3 + 2 * b + a] = d.hxt[b][(i, a)];
                    h[3 + 2 * b + a][i] = d.hxt[b][(i, a)];
                }
            }
        }
        (v, g, h)
    }

    /// Factor the Hessian in `d` into `fac`; false if not positive definite.
    fn factor(d: &Derivs, fac: &mut Factor) -> bool {
        let p = d.gt.len();
        fac.lb.clear();
        fac.c.clear();
        let mut s = d.hxx;
        let mut log_det = 0.0;
        for b in 0..p {
            let Some(ch) = d.ht[b].cholesky() else {
                return false;
            };
            let lb = ch.l();
            // C_b = B_b L_b⁻ᵀ, i.e. C_b L_bᵀ = B_b.
            let Some(lbi) = lb.try_inverse() else {
                return false;
            };
            let c = d.hxt[b] * lbi.transpose();
            s -= c * c.transpose();
            log_det += lb[(0, 0)].ln() + lb[(1, 1)].ln();
            fac.lb.push(lb);
            fac.c.push(c);
        }
        let Some(ch) = s.cholesky() else {
            return false;
        };
        fac.ls = ch.l();
        fac.log_det = log_det + (0..3).map(|i| fac.ls[(i, i)].ln()).sum::<f64>();
        fac.log_det.is_finite()
    }

    /// Evaluate at the current point and factor, exact curvature first.
    fn eval_factor(&mut self) -> Option<f64> {
        let th = std::mem::take(&mut self.th);
        let mut d = std::mem::take(&mut self.d);
        let mut val = self.eval_into(&self.x, &th, Curvature::Exact, &mut d);
        let mut ok = Self::factor(&d, &mut self.fac);
        if !ok {
            val = self.eval_into(&self.x, &th, Curvature::GaussNewton, &mut d);
            ok = Self::factor(&d, &mut self.fac);
        }
        self.d = d;
        self.th = th;
        ok.then_some(val)
    }

    /// F at (x, θ) through the spare buffer.
    fn value_buf(&mut self, x: &Pose, th: &[Point]) -> f64 {
        let mut d = std::mem::take(&mut self.dn);
        let v = self.eval_into(x, th, Curvature::GaussNewton, &mut d);
        self.dn = d;
        v
    }

    /// Solve L Lᵀ y = r (r given blockwise in `gx`, `gt`): y_x, y_θ.
    fn solve(&mut self, rx: &Vector3<f64>, rt: &[Vector2<f64>]) -> Option<Vector3<f64>> {
        // Forward: L w = r.
        let p = rt.len();
        self.step_t.clear();
        let mut wx = *rx;
        for b in 0..p {
            let wb = self.fac.lb[b].solve_lower_triangular(&rt[b])?;
            wx -= self.fac.c[b] * wb;
            self.step_t.push(wb);
        }
        let wx = self.fac.ls.solve_lower_triangular(&wx)?;
        // Backward: Lᵀ y = w.
        let yx = self.fac.ls.tr_solve_lower_triangular(&wx)?;
        for b in 0..p {
            let rhs = self.step_t[b] - self.fac.c[b].transpose() * yx;
            self.step_t[b] = self.fac.lb[b].tr_solve_lower_triangular(&rhs)?;
        }
        Some(yx)
    }

    /// Damped Newton from the current point (set by [`Arrow::push`] and
    /// `x`); leaves the minimiser in `x`, `th` and its factor in place.
    pub fn minimise(&mut self, max_iter: usize, tol: f64) -> Option<ArrowMinimum> {
        let mut val = self.eval_factor()?;
        let mut iters = 0;
        while iters < max_iter {
            let gx = self.d.gx;
            let gt = std::mem::take(&mut self.d.gt);
            let dx = -self.solve(&gx, &gt)?;
            let dec = -(gx.dot(&dx)
                - gt.iter()
                    .zip(&self.step_t)
                    .map(|(g, s)| g.dot(s))
                    .sum::<f64>());
            self.d.gt = gt;
            if !dec.is_finite() {
                return None;
            }
            if dec < tol {
                break;
            }
            let x0 = self.x;
            let mut t = 1.0;
            let mut accepted = false;
            for _ in 0..30 {
                let xt = x0 + dx * t;
                self.th_try.clear();
                for (th, s) in self.th.iter().zip(&self.step_t) {
                    self.th_try.push([th[0] - s[0] * t, th[1] - s[1] * t]);
                }
                let mut dn = std::mem::take(&mut self.dn);
                let fv = self.eval_into(&xt, &self.th_try, Curvature::Exact, &mut dn);
                self.dn = dn;
                if fv <= val - 1e-4 * t * dec {
                    self.x = xt;
                    std::mem::swap(&mut self.th, &mut self.th_try);
                    // The trial's exact derivatives are the new point's:
                    // factor them, re-evaluating only for Gauss–Newton.
                    if Self::factor(&self.dn, &mut self.fac) {
                        std::mem::swap(&mut self.d, &mut self.dn);
                        val = fv;
                    } else {
                        val = self.eval_factor()?;
                    }
                    accepted = true;
                    break;
                }
                t *= 0.5;
            }
            iters += 1;
            if !accepted {
                break;
            }
        }
        (val.is_finite() && self.x.iter().all(|c| c.is_finite())).then_some(ArrowMinimum {
            phi: val,
            log_det_l: self.fac.log_det,
            iters,
        })
    }

    /// The linear map from the minimum: writes the draw into `x_out`,
    /// `th_out` and returns ½ξᵀξ − F(v) − log det L. ξ_x and ξ_θ are
    /// standard normals (ξ_θ: one pair per feature).
    pub fn draw(
        &mut self,
        xi_x: &Vector3<f64>,
        xi_t: &[Vector2<f64>],
        x_out: &mut Pose,
        th_out: &mut Vec<Point>,
    ) -> Option<f64> {
        // Lᵀ y = ξ: y_x = L_S⁻ᵀ ξ_x, y_b = L_b⁻ᵀ (ξ_b − C_bᵀ y_x).
        let yx = self.fac.ls.tr_solve_lower_triangular(xi_x)?;
        *x_out = self.x + yx;
        th_out.clear();
        let mut q = xi_x.dot(xi_x);
        for (b, xb) in xi_t.iter().enumerate() {
            let yb =
                self.fac.lb[b].tr_solve_lower_triangular(&(xb - self.fac.c[b].transpose() * yx))?;
            th_out.push([self.th[b][0] + yb[0], self.th[b][1] + yb[1]]);
            q += xb.dot(xb);
        }
        let inc = 0.5 * q - self.value_buf(x_out, th_out) - self.fac.log_det;
        inc.is_finite().then_some(inc)
    }

    /// θ_b's block of H⁻¹ at the minimum: D_b⁻¹ + D_b⁻¹ B_bᵀ S⁻¹ B_b D_b⁻¹.
    pub fn cov(&self, b: usize) -> Option<Matrix2<f64>> {
        let lbi = self.fac.lb[b].try_inverse()?;
        let dinv = lbi.transpose() * lbi;
        let lsi = self.fac.ls.try_inverse()?;
        let sinv = lsi.transpose() * lsi;
        let k = self.d.hxt[b] * dinv;
        Some(dinv + k.transpose() * sinv * k)
    }
}
