//! The filter's measurement updates: a heading reading (gated, re-anchored after a lasting
//! step), a position fix, a pose of a reference frame mounted on the robot (anchored by the first
//! fix), and a start from a batch pose fit.

use super::*;

impl OnlineEstimator {
    /// Updates with a heading reading (rad, counter-clockwise positive). Returns the
    /// normalised innovation squared, or `None` for the first reading (it sets the heading), a
    /// non-finite one, or one rejected by the gate.
    pub fn update_heading(&mut self, heading_rad: f64) -> Option<f64> {
        if !heading_rad.is_finite() {
            return None;
        }
        let r = self.cfg.heading_sigma_rad.powi(2);
        if !self.heading_initialized {
            self.x[TH] = wrap_angle(heading_rad - self.x[BIAS]);
            self.p[(TH, TH)] = r;
            self.heading_initialized = true;
            return None;
        }
        let mut h = SVector::<f64, N>::zeros();
        h[TH] = 1.0;
        if self.cfg.estimate_heading_bias {
            h[BIAS] = 1.0;
        }
        let innovation = wrap_angle(heading_rad - (self.x[TH] + self.x[BIAS]));
        let ph = self.p * h;
        let s = h.dot(&ph) + r;
        let nis = innovation * innovation / s;
        if nis > self.cfg.gate_nis {
            self.gate.rejected += 1;
            self.rejected_in_a_row += 1;
            if self.rejected_in_a_row >= self.cfg.gate_recover_after.max(1) {
                // A lasting step, not a glitch: take the heading from here, keep the parameters.
                for j in 0..N {
                    self.p[(TH, j)] = 0.0;
                    self.p[(j, TH)] = 0.0;
                }
                self.x[TH] = wrap_angle(heading_rad - self.x[BIAS]);
                self.p[(TH, TH)] = r;
                self.gate.resets += 1;
                self.rejected_in_a_row = 0;
            }
            return None;
        }
        self.rejected_in_a_row = 0;
        self.gate.accepted += 1;
        let kgain = ph / s;
        self.x += kgain * innovation;
        self.x[TH] = wrap_angle(self.x[TH]);
        // Joseph form keeps P symmetric and positive over millions of updates.
        let ikh = Matrix::identity() - kgain * h.transpose();
        self.p = ikh * self.p * ikh.transpose() + kgain * kgain.transpose() * r;
        self.nis_heading.0 += nis;
        self.nis_heading.1 += 1;
        Some(nis)
    }

    /// Updates with an absolute position fix (m, in the frame the run started in). Returns the
    /// normalised innovation squared.
    pub fn update_position(&mut self, x_m: f64, y_m: f64) -> Option<f64> {
        if !(x_m.is_finite() && y_m.is_finite()) {
            return None;
        }
        let r = self.cfg.position_sigma_m.powi(2);
        let mut h = SMatrix::<f64, 2, N>::zeros();
        h[(0, X)] = 1.0;
        h[(1, Y)] = 1.0;
        let nu = Vector2::new(x_m - self.x[X], y_m - self.x[Y]);
        let s = h * self.p * h.transpose() + Matrix2::identity() * r;
        let s_inv = s.try_inverse()?;
        let kgain = self.p * h.transpose() * s_inv;
        self.x += kgain * nu;
        let ikh = Matrix::identity() - kgain * h;
        self.p = ikh * self.p * ikh.transpose() + kgain * kgain.transpose() * r;
        let nis = (nu.transpose() * s_inv * nu)[(0, 0)];
        self.nis_position.0 += nis;
        self.nis_position.1 += 1;
        Some(nis)
    }

    /// Updates with a pose of the reference frame in the reference's world frame (m, m and
    /// rad; `yaw_rad` `None` for a position-only reference) with standard deviations
    /// `sigma` (x, y in m, yaw in rad; `None`: the configured `position_sigma_m` and
    /// `heading_sigma_rad`). The first fix of a run anchors the pose (it needs a yaw): the
    /// filter's world becomes the reference's, the pose's uncertainty the mounting's. A fix
    /// whose NIS exceeds χ² at 99.9 % (a relocalisation, a marker swap) is rejected and
    /// counted; `gate_recover_after` rejections in a row re-anchor the pose to the reference,
    /// keeping the parameters. Returns the NIS of an accepted fix.
    pub fn update_pose(
        &mut self,
        x_m: f64,
        y_m: f64,
        yaw_rad: Option<f64>,
        sigma: Option<[f64; 3]>,
    ) -> Option<f64> {
        if !(x_m.is_finite() && y_m.is_finite() && yaw_rad.is_none_or(f64::is_finite)) {
            return None;
        }
        let [sx, sy, syaw] = self.fix_sigmas(yaw_rad, sigma);
        if !self.anchored {
            let Some(yaw) = yaw_rad else {
                // A position-only fix cannot tell which way the robot faces.
                return None;
            };
            self.anchor(x_m, y_m, yaw, [sx * sx, sy * sy, syaw * syaw]);
            return None;
        }
        let dim = if yaw_rad.is_some() { 3 } else { 2 };
        let r = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(
            sx * sx,
            sy * sy,
            if yaw_rad.is_some() { syaw * syaw } else { 1.0 },
        ));
        let fix = PoseFix { x_m, y_m, yaw_rad };
        let (h0, nu0) = fix.linearise(&self.x);
        let s_inv = (h0 * self.p * h0.transpose() + r).try_inverse()?;
        let nis = (nu0.transpose() * s_inv * nu0)[(0, 0)];
        let gate = if dim == 3 { CHI2_3_999 } else { CHI2_2_999 };
        if nis.is_nan() || nis > gate {
            self.reject_pose_fix(&fix, [sx, sy, syaw]);
            return None;
        }
        self.rejected_in_a_row = 0;
        self.gate.accepted += 1;
        let (x, h, kgain) = self.iterate_pose_fix(&fix, r, h0, nu0, s_inv);
        self.x = x;
        self.x[TH] = wrap_angle(self.x[TH]);
        self.x[MPSI] = wrap_angle(self.x[MPSI]);
        let ikh = Matrix::identity() - kgain * h;
        self.p = ikh * self.p * ikh.transpose() + kgain * r * kgain.transpose();
        self.nis_pose.0 += nis / dim as f64;
        self.nis_pose.1 += 1;
        Some(nis)
    }

    /// The standard deviations `(x, y, yaw)` to take for a pose fix stating `sigma`.
    fn fix_sigmas(&self, yaw_rad: Option<f64>, sigma: Option<[f64; 3]>) -> [f64; 3] {
        // Stated deviations as the start's batch fit scaled them (a localization's covariance
        // is a weight, seldom a calibrated variance); none stated: the fit's residual scatter,
        // else the configured noise. Only the components used must be stated (a position-only
        // reference states no yaw).
        let usable = |v: f64| v.is_finite() && v > 0.0;
        let stated =
            sigma.filter(|s| usable(s[0]) && usable(s[1]) && (yaw_rad.is_none() || usable(s[2])));
        let noise = self.fix_noise;
        match stated {
            Some(s) => [
                s[0] * noise.stated_scale[0],
                s[1] * noise.stated_scale[0],
                if usable(s[2]) {
                    s[2] * noise.stated_scale[1]
                } else {
                    self.cfg.heading_sigma_rad
                },
            ],
            None => noise.unstated.unwrap_or([
                self.cfg.position_sigma_m,
                self.cfg.position_sigma_m,
                self.cfg.heading_sigma_rad,
            ]),
        }
    }

    /// Counts a pose fix the gate rejected, re-anchoring to it after enough in a row.
    fn reject_pose_fix(&mut self, fix: &PoseFix, [sx, sy, syaw]: [f64; 3]) {
        self.gate.rejected += 1;
        self.rejected_in_a_row += 1;
        if self.rejected_in_a_row >= self.cfg.gate_recover_after.max(1) {
            if let Some(yaw) = fix.yaw_rad {
                // The reference moved its world (a relocalisation): start from it again.
                self.anchor(fix.x_m, fix.y_m, yaw, [sx * sx, sy * sy, syaw * syaw]);
                self.gate.resets += 1;
            }
            self.rejected_in_a_row = 0;
        }
    }

    /// The state after an accepted pose fix (angles not yet wrapped: the caller wraps them),
    /// with the last Jacobian and gain, by iterated update.
    fn iterate_pose_fix(
        &self,
        fix: &PoseFix,
        r: nalgebra::Matrix3<f64>,
        h0: SMatrix<f64, 3, N>,
        nu0: nalgebra::Vector3<f64>,
        s_inv: nalgebra::Matrix3<f64>,
    ) -> (Vector, SMatrix<f64, 3, N>, SMatrix<f64, N, 3>) {
        // Iterated update (Gauss–Newton on the posterior): the lever arm turns with the
        // heading, so a fix linearised where the mounting is still unknown (at first, zero:
        // no lever arm for the heading to turn) misplaces it; relinearising at the updated
        // state, a few times, does not.
        let prior = self.x;
        let (mut h, mut kgain) = (h0, self.p * h0.transpose() * s_inv);
        let mut x = prior + kgain * nu0;
        for _ in 0..4 {
            let (hi, nui) = fix.linearise(&x);
            let Some(si_inv) = (hi * self.p * hi.transpose() + r).try_inverse() else {
                break;
            };
            let ki = self.p * hi.transpose() * si_inv;
            let mut dx = prior - x;
            dx[TH] = wrap_angle(dx[TH]);
            dx[MPSI] = wrap_angle(dx[MPSI]);
            let next = prior + ki * (nui - hi * dx);
            let moved = (next - x).amax();
            (x, h, kgain) = (next, hi, ki);
            if moved < 1e-9 {
                break;
            }
        }
        (x, h, kgain)
    }

    /// Starts the parameters and the pose reference's mounting from a batch fit of the drive so
    /// far ([`crate::calibration::pose_fit`]): its values, and its covariance carried into the state's
    /// (`u = (D/D_cfg)/E_b`, `k = E_b = b/b_cfg`); the pose waits for the next fix to anchor
    /// it. With fixes alone the filter's first metres are a bilinear problem (the lever arm
    /// turns with a heading the mounting's yaw leaves unknown) that a linearised update
    /// resolves wrongly and then trusts; the batch fit solves it where the drive observed it.
    pub fn start_from_fit(&mut self, fit: &crate::calibration::pose_fit::PoseFit) {
        let cfg = &self.cfg.configured;
        let [dl, dr, b, mx, my, mpsi, _] = fit.params;
        let k = b / cfg.wheelbase_m;
        let (ul, ur) = (
            dl / cfg.left_wheel_diameter_m / k,
            dr / cfg.right_wheel_diameter_m / k,
        );
        // ∂(u_L, u_R, k, m_x, m_y, m_ψ)/∂(D_L, D_R, b, x, y, ψ).
        let mut j = SMatrix::<f64, 6, 6>::zeros();
        j[(0, 0)] = ul / dl;
        j[(0, 2)] = -ul / b;
        j[(1, 1)] = ur / dr;
        j[(1, 2)] = -ur / b;
        j[(2, 2)] = 1.0 / cfg.wheelbase_m;
        for i in 3..6 {
            j[(i, i)] = 1.0;
        }
        let c = SMatrix::<f64, 6, 6>::from_fn(|a, bb| fit.covariance[a][bb]);
        let cs = j * c * j.transpose();
        let states = [UL, UR, K, MX, MY, MPSI];
        let finite = cs.iter().all(|v| v.is_finite());
        for (a, &i) in states.iter().enumerate() {
            for jj in 0..N {
                self.p[(i, jj)] = 0.0;
                self.p[(jj, i)] = 0.0;
            }
            for (bb, &jj) in states.iter().enumerate() {
                self.p[(i, jj)] = if finite {
                    cs[(a, bb)]
                } else if a == bb {
                    self.prior[(i, i)]
                } else {
                    0.0
                };
            }
        }
        self.x[UL] = ul;
        self.x[UR] = ur;
        self.x[K] = k;
        self.x[MX] = mx;
        self.x[MY] = my;
        self.x[MPSI] = wrap_angle(mpsi);
        let position = fit.residual_std_position_m;
        self.fix_noise = FixNoise {
            stated_scale: [fit.stated_scale, fit.stated_scale_yaw]
                .map(|s| s.filter(|s| s.is_finite() && *s > 0.0).unwrap_or(1.0)),
            unstated: (position.is_finite() && position > 0.0).then(|| {
                [
                    position,
                    position,
                    fit.residual_std_yaw_rad
                        .filter(|s| s.is_finite() && *s > 0.0)
                        .unwrap_or(self.cfg.heading_sigma_rad),
                ]
            }),
        };
        self.restart_pose();
    }

    /// Puts the pose where the reference fix `(x, y, yaw)` (variances `r`) and the current
    /// mounting say, with the uncertainty the mounting's carries into it (its cross-covariance
    /// kept, so that later fixes separate the two).
    pub(super) fn anchor(&mut self, x_m: f64, y_m: f64, yaw_rad: f64, r: [f64; 3]) {
        let (mx, my, mpsi) = (self.x[MX], self.x[MY], self.x[MPSI]);
        let th = wrap_angle(yaw_rad - mpsi);
        let (s, c) = th.sin_cos();
        // pose = g(fix, m): θ = ψ − m_ψ, (x, y) = p − R(θ)(m_x, m_y); its Jacobian in m.
        let mut jm = SMatrix::<f64, 3, N>::zeros();
        jm[(0, MX)] = -c;
        jm[(0, MY)] = s;
        jm[(0, MPSI)] = -(s * mx + c * my);
        jm[(1, MX)] = -s;
        jm[(1, MY)] = -c;
        jm[(1, MPSI)] = c * mx - s * my;
        jm[(2, MPSI)] = -1.0;
        for i in [X, Y, TH] {
            for j in 0..N {
                self.p[(i, j)] = 0.0;
                self.p[(j, i)] = 0.0;
            }
        }
        let cross = jm * self.p; // 3 × N: the pose's covariance with every state.
        let pose_cov = cross * jm.transpose();
        for (a, i) in [X, Y, TH].into_iter().enumerate() {
            for j in 0..N {
                self.p[(i, j)] = cross[(a, j)];
                self.p[(j, i)] = cross[(a, j)];
            }
        }
        // The fix's own noise, its yaw's through the lever arm too: J_z R J_zᵀ.
        let jz = nalgebra::Matrix3::new(
            1.0,
            0.0,
            s * mx + c * my,
            0.0,
            1.0,
            -(c * mx - s * my),
            0.0,
            0.0,
            1.0,
        );
        let noise =
            jz * nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::from(r)) * jz.transpose();
        for (a, i) in [X, Y, TH].into_iter().enumerate() {
            for (b, j) in [X, Y, TH].into_iter().enumerate() {
                self.p[(i, j)] = pose_cov[(a, b)] + noise[(a, b)];
            }
        }
        self.x[X] = x_m - (c * mx - s * my);
        self.x[Y] = y_m - (s * mx + c * my);
        self.x[TH] = th;
        self.anchored = true;
        self.heading_initialized = true;
    }
}

/// The noise of pose fixes as a batch fit of the drive found it.
#[derive(Debug, Clone, Copy)]
pub(super) struct FixNoise {
    /// Factors on the standard deviations a fix states (position, yaw).
    pub(super) stated_scale: [f64; 2],
    /// Standard deviations of fixes that state none (x, y in m; yaw in rad).
    pub(super) unstated: Option<[f64; 3]>,
}

/// One pose fix of the reference frame (m, m and rad; yaw `None` for a position-only one).
struct PoseFix {
    x_m: f64,
    y_m: f64,
    yaw_rad: Option<f64>,
}

impl PoseFix {
    /// The fix's Jacobian and innovation at state `x` (position only: the yaw row drops out —
    /// zero row, unit variance, zero innovation: it neither informs nor counts).
    fn linearise(&self, x: &Vector) -> (SMatrix<f64, 3, N>, nalgebra::Vector3<f64>) {
        let (x_m, y_m, yaw_rad) = (self.x_m, self.y_m, self.yaw_rad);
        let (s, c) = x[TH].sin_cos();
        let (mx, my) = (x[MX], x[MY]);
        let mut h = SMatrix::<f64, 3, N>::zeros();
        h[(0, X)] = 1.0;
        h[(0, TH)] = -s * mx - c * my;
        h[(0, MX)] = c;
        h[(0, MY)] = -s;
        h[(1, Y)] = 1.0;
        h[(1, TH)] = c * mx - s * my;
        h[(1, MX)] = s;
        h[(1, MY)] = c;
        let mut nu = nalgebra::Vector3::new(
            x_m - (x[X] + c * mx - s * my),
            y_m - (x[Y] + s * mx + c * my),
            0.0,
        );
        if let Some(yaw) = yaw_rad {
            h[(2, TH)] = 1.0;
            h[(2, MPSI)] = 1.0;
            nu[2] = wrap_angle(yaw - (x[TH] + x[MPSI]));
        }
        (h, nu)
    }
}
