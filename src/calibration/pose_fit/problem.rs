//! The fit's problem: for a candidate `p`, the odometry predicted along the reference's
//! samples, the residuals (absolute: aligned per window; relative: per increment), their
//! whitening by the noise model and the numeric Jacobian of the whitened residuals.

use super::*;

/// The least-squares problem for one kind.
pub(super) struct Problem<'a> {
    pub(super) recording: &'a PoseRecording,
    /// Indices of the reference poses compared.
    pub(super) selected: Vec<usize>,
    pub(super) kind: ReferenceKind,
    pub(super) dim: usize,
    /// Windows over `selected` (absolute): `[start, end)`.
    pub(super) windows: Vec<(usize, usize)>,
    pub(super) free: Vec<Param>,
    pub(super) tie: bool,
    pub(super) fixed: [f64; PARAMS],
    pub(super) max_offset: f64,
    /// Whether the stated standard deviations weight the samples: only for an absolute
    /// reference (a pose's σ is not its increment's) whose every sample states one (a mix
    /// would weigh the two kinds of sample by unrelated units).
    pub(super) use_stated: bool,
    /// The reference's motion between consecutive selected samples (relative), computed once.
    pub(super) reference_steps: Vec<Pose2>,
}

impl<'a> Problem<'a> {
    pub(super) fn new(
        recording: &'a PoseRecording,
        config: &FitConfig,
        kind: ReferenceKind,
    ) -> Result<Self, CalibrationError> {
        let has_yaw = recording.has_yaw();
        // A largest offset of zero is no offset to fit (its column would be zero).
        let fit_offset = config.fit_time_offset && config.max_time_offset_s > 0.0;
        let margin = if fit_offset {
            config.max_time_offset_s
        } else {
            0.0
        };
        let selected = select_poses(recording, kind, margin)?;
        let free = free_params(config, has_yaw, fit_offset);
        let windows = match (kind, config.window_s) {
            (ReferenceKind::Relative, _) | (_, None) => vec![(0, selected.len())],
            (ReferenceKind::Absolute, Some(w)) => {
                merge_short_windows(time_windows(recording, &selected, w))
            }
        };
        let g = config.nominal;
        let use_stated = kind == ReferenceKind::Absolute
            && selected
                .iter()
                .all(|&i| recording.poses[i].stated_std.is_some());
        Ok(Self {
            recording,
            kind,
            dim: if has_yaw { 3 } else { 2 },
            windows,
            free,
            tie: config.tie_diameters,
            fixed: [
                g.left_diameter_m,
                g.right_diameter_m,
                g.wheelbase_m,
                0.0,
                0.0,
                0.0,
                0.0,
            ],
            max_offset: margin,
            use_stated,
            reference_steps: match kind {
                ReferenceKind::Relative => reference_steps(recording, &selected),
                ReferenceKind::Absolute => Vec::new(),
            },
            selected,
        })
    }

    pub(super) fn blocks(&self) -> usize {
        match self.kind {
            ReferenceKind::Absolute => self.selected.len(),
            ReferenceKind::Relative => self.selected.len() - 1,
        }
    }

    /// The full parameter vector from the free values.
    pub(super) fn full(&self, x: &[f64]) -> [f64; PARAMS] {
        let mut p = self.fixed;
        for (v, param) in x.iter().zip(&self.free) {
            p[param.index()] = *v;
        }
        if self.tie {
            p[1] = p[0];
        }
        p
    }

    pub(super) fn free_values(&self, p: &[f64; PARAMS]) -> Vec<f64> {
        self.free.iter().map(|q| p[q.index()]).collect()
    }

    pub(super) fn geometry(p: &[f64; PARAMS]) -> Geometry {
        Geometry {
            left_diameter_m: p[0],
            right_diameter_m: p[1],
            wheelbase_m: p[2],
        }
    }

    /// The stated standard deviation of component `c` of block `b` (1 when none is stated).
    pub(super) fn stated(&self, block: usize, c: usize) -> f64 {
        let i = match self.kind {
            ReferenceKind::Absolute => self.selected[block],
            ReferenceKind::Relative => self.selected[block + 1],
        };
        if !self.use_stated {
            return 1.0;
        }
        self.recording.poses[i].stated_std.map_or(1.0, |s| s[c])
    }

    /// Root mean square of the stated standard deviation of component `c` (1 when the
    /// samples are not weighted by what they state).
    pub(super) fn stated_rms(&self, c: usize) -> f64 {
        if !self.use_stated || self.blocks() == 0 {
            return 1.0;
        }
        let sum: f64 = (0..self.blocks()).map(|b| self.stated(b, c).powi(2)).sum();
        (sum / self.blocks() as f64).sqrt()
    }

    /// The predicted reference-frame poses at the selected stamps, before any alignment.
    pub(super) fn predicted(
        &self,
        odo: &Odometry<'_>,
        p: &[f64; PARAMS],
    ) -> (Vec<Pose2>, Vec<Turn>) {
        let mount = Pose2 {
            x: p[3],
            y: p[4],
            theta: p[5],
        };
        let mount_turn = Turn::of(mount.theta);
        let delta = p[6].clamp(-self.max_offset, self.max_offset);
        let mut hint = 0;
        let last = odo
            .poses()
            .last()
            .map(|q| (*q, Turn::of(q.theta)))
            .unwrap_or((Pose2::default(), Turn::of(0.0)));
        self.selected
            .iter()
            .map(|&i| {
                let t = self.recording.poses[i].time_s - delta;
                let (base, turn) = odo.at_turned(t, &mut hint).unwrap_or(last);
                (base.compose_turned(turn, &mount), turn.then(mount_turn))
            })
            .unzip()
    }

    /// Residuals (reference minus prediction) for parameters `p`, block after block, `dim`
    /// components each; `weights` and `scales` set the alignment's weights.
    pub(super) fn residuals(
        &self,
        odo: &Odometry<'_>,
        p: &[f64; PARAMS],
        weights: &[f64],
        scales: Scales,
    ) -> Vec<f64> {
        let (pred, turns) = self.predicted(odo, p);
        let dim = self.dim;
        let mut out = Vec::with_capacity(self.blocks() * dim);
        match self.kind {
            ReferenceKind::Absolute => {
                for &(a, b) in &self.windows {
                    let mut align = self.align(&pred[a..b], a, weights, scales);
                    if scales.walks() {
                        align = self.align_whitened(&pred, a, b, align, weights, scales);
                    }
                    out.extend(self.window_residuals(&pred, a, b, &align));
                }
            }
            ReferenceKind::Relative => {
                for (k, rd) in self.reference_steps.iter().enumerate() {
                    let pd = pred[k].between_turned(turns[k], &pred[k + 1]);
                    out.push(rd.x - pd.x);
                    out.push(rd.y - pd.y);
                    if dim == 3 {
                        out.push(wrap_angle(rd.theta - pd.theta));
                    }
                }
            }
        }
        out
    }

    /// The world-from-odometry alignment of one window: weighted Procrustes on the positions,
    /// refined by the yaws.
    pub(super) fn align(
        &self,
        pred: &[Pose2],
        first: usize,
        weights: &[f64],
        scales: Scales,
    ) -> Pose2 {
        let poses = &self.recording.poses;
        let (mut sw, mut cq, mut cr) = (0.0, [0.0; 2], [0.0; 2]);
        for (k, q) in pred.iter().enumerate() {
            let b = first + k;
            let w = weights[b] / (0.5 * (self.stated(b, 0).powi(2) + self.stated(b, 1).powi(2)));
            let r = &poses[self.selected[b]];
            sw += w;
            cq[0] += w * q.x;
            cq[1] += w * q.y;
            cr[0] += w * r.x_m;
            cr[1] += w * r.y_m;
        }
        if sw <= 0.0 {
            return Pose2::default();
        }
        for c in cq.iter_mut().chain(cr.iter_mut()) {
            *c /= sw;
        }
        let (mut sc, mut ss) = (0.0, 0.0);
        for (k, q) in pred.iter().enumerate() {
            let b = first + k;
            let w = weights[b] / (0.5 * (self.stated(b, 0).powi(2) + self.stated(b, 1).powi(2)));
            let r = &poses[self.selected[b]];
            let (qx, qy) = (q.x - cq[0], q.y - cq[1]);
            let (rx, ry) = (r.x_m - cr[0], r.y_m - cr[1]);
            sc += w * (qx * rx + qy * ry);
            ss += w * (qx * ry - qy * rx);
        }
        let mut phi = ss.atan2(sc);
        if self.dim == 3 {
            // The position cost is −2A·cos(φ − φ_p) (curvature 2A/σ_p²); the yaw cost is
            // quadratic (curvature 2Σw/σ_ψ²): one Newton step on their sum, twice.
            let k_pos = sc.hypot(ss) / scales.position.powi(2);
            for _ in 0..2 {
                let (mut wy, mut off) = (0.0, 0.0);
                for (k, q) in pred.iter().enumerate() {
                    let b = first + k;
                    let w = weights[b] / self.stated(b, 2).powi(2);
                    if let Some(yaw) = poses[self.selected[b]].yaw_rad {
                        wy += w;
                        off += w * wrap_angle(yaw - q.theta - phi);
                    }
                }
                if wy <= 0.0 {
                    break;
                }
                let k_yaw = wy / scales.yaw.powi(2);
                let pos_pull = {
                    let (s, c) = (ss, sc);
                    // d/dφ of −(c·cosφ + s·sinφ) at φ, over its curvature: the position
                    // cost's own Newton step.
                    (s * phi.cos() - c * phi.sin()) / scales.position.powi(2)
                };
                phi += (pos_pull + k_yaw * off / wy) / (k_pos + k_yaw);
            }
        }
        let (s, c) = phi.sin_cos();
        Pose2 {
            x: cr[0] - (c * cq[0] - s * cq[1]),
            y: cr[1] - (s * cq[0] + c * cq[1]),
            theta: phi,
        }
    }

    /// The time of block `b` (s, reference clock).
    pub(super) fn block_time(&self, b: usize) -> f64 {
        let i = match self.kind {
            ReferenceKind::Absolute => self.selected[b],
            ReferenceKind::Relative => self.selected[b + 1],
        };
        self.recording.poses[i].time_s
    }

    /// The residuals of one window for an alignment.
    pub(super) fn window_residuals(
        &self,
        pred: &[Pose2],
        a: usize,
        b: usize,
        align: &Pose2,
    ) -> Vec<f64> {
        let poses = &self.recording.poses;
        let mut out = Vec::with_capacity((b - a) * self.dim);
        let turn = Turn::of(align.theta);
        for k in a..b {
            let q = align.compose_turned(turn, &pred[k]);
            let r = &poses[self.selected[k]];
            out.push(r.x_m - q.x);
            out.push(r.y_m - q.y);
            if let Some(yaw) = r.yaw_rad {
                out.push(wrap_angle(yaw - q.theta));
            }
        }
        out
    }

    /// Under a random walk the Procrustes alignment is no longer the likelihood's: two
    /// Gauss–Newton steps on the whitened residuals of the window, over `(t_x, t_y, φ)`.
    pub(super) fn align_whitened(
        &self,
        pred: &[Pose2],
        a: usize,
        b: usize,
        mut align: Pose2,
        weights: &[f64],
        scales: Scales,
    ) -> Pose2 {
        let dim = self.dim;
        for _ in 0..2 {
            let e = self.window_residuals(pred, a, b, &align);
            // ∂e/∂t_x = (−1, 0, 0), ∂e/∂t_y = (0, −1, 0), ∂e/∂φ = (y − t_y, −(x − t_x), −1).
            let mut cols = vec![vec![0.0; e.len()]; 3];
            let turn = Turn::of(align.theta);
            for (k, pk) in pred[a..b].iter().enumerate() {
                let q = align.compose_turned(turn, pk);
                let i = k * dim;
                cols[0][i] = -1.0;
                cols[1][i + 1] = -1.0;
                cols[2][i] = q.y - align.y;
                cols[2][i + 1] = -(q.x - align.x);
                if dim == 3 {
                    cols[2][i + 2] = -1.0;
                }
            }
            let z = self.whiten_window(&e, a, b, weights, scales).0;
            let zc: Vec<Vec<f64>> = cols
                .iter()
                .map(|c| self.whiten_window(c, a, b, weights, scales).0)
                .collect();
            let mut h = nalgebra::Matrix3::<f64>::zeros();
            let mut g = nalgebra::Vector3::<f64>::zeros();
            for i in 0..z.len() {
                for r in 0..3 {
                    g[r] += zc[r][i] * z[i];
                    for c in 0..3 {
                        h[(r, c)] += zc[r][i] * zc[c][i];
                    }
                }
            }
            let Some(step) = h.cholesky().map(|ch| ch.solve(&(-g))) else {
                break;
            };
            align.x += step[0];
            align.y += step[1];
            align.theta += step[2];
        }
        align
    }

    /// Whitens residuals `e` of blocks `[a, b)`: returns the whitened residuals the cost sums
    /// (zero for a block left out, scaled by its weight) and the innovations normalised
    /// without the weights (for judging outliers). Under a random walk each component is
    /// the innovation of a scalar Kalman filter whose state starts at zero with the window
    /// (the alignment plays its initial value); a block left out is not used to update it.
    pub(super) fn whiten_window(
        &self,
        e: &[f64],
        a: usize,
        b: usize,
        weights: &[f64],
        scales: Scales,
    ) -> (Vec<f64>, Vec<f64>) {
        let dim = self.dim;
        let mut z = vec![0.0; e.len()];
        let mut raw = vec![0.0; e.len()];
        let walk = scales.walks() && self.kind == ReferenceKind::Absolute;
        for c in 0..dim {
            let (sigma, q) = scales.of(c);
            let (mut m, mut var) = (0.0, 0.0);
            let mut t_prev: Option<f64> = None;
            for (blk, &w) in weights.iter().enumerate().take(b).skip(a) {
                let i = (blk - a) * dim + c;
                let meas = (sigma * self.stated(blk, c)).powi(2);
                if !walk {
                    raw[i] = e[i] / meas.sqrt();
                    z[i] = raw[i] * w.sqrt();
                    continue;
                }
                let t = self.block_time(blk);
                if let Some(tp) = t_prev {
                    var += q * (t - tp).max(0.0);
                }
                t_prev = Some(t);
                let nu = e[i] - m;
                raw[i] = nu / (var + meas).sqrt();
                if w > 0.0 {
                    let s = var + meas / w;
                    z[i] = nu / s.sqrt();
                    let k = var / s;
                    m += k * nu;
                    var *= 1.0 - k;
                }
            }
        }
        (z, raw)
    }

    /// Whitens a whole residual vector (all blocks, window by window).
    pub(super) fn whiten(
        &self,
        e: &[f64],
        weights: &[f64],
        scales: Scales,
    ) -> (Vec<f64>, Vec<f64>) {
        let dim = self.dim;
        let windows: Vec<(usize, usize)> = match self.kind {
            ReferenceKind::Absolute => self.windows.clone(),
            ReferenceKind::Relative => vec![(0, self.blocks())],
        };
        let mut z = Vec::with_capacity(e.len());
        let mut raw = Vec::with_capacity(e.len());
        for (a, b) in windows {
            let (zw, rw) = self.whiten_window(&e[a * dim..b * dim], a, b, weights, scales);
            z.extend(zw);
            raw.extend(rw);
        }
        (z, raw)
    }

    /// The residuals at `x` and their Jacobian with respect to the free parameters.
    pub(super) fn jacobian(
        &self,
        x: &[f64],
        weights: &[f64],
        scales: Scales,
    ) -> (Vec<f64>, DMatrix<f64>) {
        let p = self.full(x);
        let wheels = &self.recording.wheels;
        let odo = Odometry::integrate(wheels, Self::geometry(&p));
        let r0 = self.residuals(&odo, &p, weights, scales);
        // One column per free parameter; the columns are independent, so they are computed on
        // as many threads as there are cores (two columns at least per thread).
        let column = |j: usize| -> Vec<f64> {
            let param = self.free[j];
            let h = step(param, &p);
            if param.is_geometry() {
                // Forward difference: each side needs a new integration.
                let mut xp = x.to_vec();
                xp[j] += h;
                let pp = self.full(&xp);
                let odo_p = Odometry::integrate(wheels, Self::geometry(&pp));
                let rp = self.residuals(&odo_p, &pp, weights, scales);
                rp.iter()
                    .zip(&r0)
                    .enumerate()
                    .map(|(i, (a, b))| angle_aware_diff(*a, *b, i, self.dim) / h)
                    .collect()
            } else {
                let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
                xp[j] += h;
                xm[j] -= h;
                let (pp, pm) = (self.full(&xp), self.full(&xm));
                let rp = self.residuals(&odo, &pp, weights, scales);
                let rm = self.residuals(&odo, &pm, weights, scales);
                rp.iter()
                    .zip(&rm)
                    .enumerate()
                    .map(|(i, (a, b))| angle_aware_diff(*a, *b, i, self.dim) / (2.0 * h))
                    .collect()
            }
        };
        let n = self.free.len();
        let threads = std::thread::available_parallelism()
            .map_or(1, |t| t.get())
            .min(n.div_ceil(2))
            .max(1);
        let columns: Vec<Vec<f64>> = if threads == 1 || r0.len() < 5_000 {
            (0..n).map(column).collect()
        } else {
            std::thread::scope(|scope| {
                let handles: Vec<_> = (0..threads)
                    .map(|t| {
                        let column = &column;
                        scope.spawn(move || {
                            (t..n)
                                .step_by(threads)
                                .map(|j| (j, column(j)))
                                .collect::<Vec<_>>()
                        })
                    })
                    .collect();
                let mut out = vec![Vec::new(); n];
                for h in handles {
                    // A column's thread fails only by panicking, which is a bug: it goes on
                    // up as the panic it is, never as a silent zero column.
                    let cols = h.join().unwrap_or_else(|e| std::panic::resume_unwind(e));
                    for (j, col) in cols {
                        out[j] = col;
                    }
                }
                out
            })
        };
        let mut jac = DMatrix::zeros(r0.len(), n);
        for (j, col) in columns.iter().enumerate() {
            for (i, v) in col.iter().enumerate() {
                jac[(i, j)] = *v;
            }
        }
        (r0, jac)
    }

    /// Residuals at `p`: the wheels integrated for its geometry, compared with the reference.
    pub(super) fn residuals_at(
        &self,
        p: &[f64; PARAMS],
        weights: &[f64],
        scales: Scales,
    ) -> Vec<f64> {
        let odo = Odometry::integrate(&self.recording.wheels, Self::geometry(p));
        self.residuals(&odo, p, weights, scales)
    }

    /// The whitened cost at `x`: the sum of the squared whitened residuals.
    pub(super) fn cost(&self, x: &[f64], weights: &[f64], scales: Scales) -> f64 {
        let r = self.residuals_at(&self.full(x), weights, scales);
        self.whiten(&r, weights, scales)
            .0
            .iter()
            .map(|z| z * z)
            .sum()
    }

    /// The whitened residuals and Jacobian at `x`.
    pub(super) fn whitened_jacobian(
        &self,
        x: &[f64],
        weights: &[f64],
        scales: Scales,
    ) -> (Vec<f64>, DMatrix<f64>) {
        let (r, jac) = self.jacobian(x, weights, scales);
        let z = self.whiten(&r, weights, scales).0;
        let mut jz = DMatrix::zeros(z.len(), jac.ncols());
        for j in 0..jac.ncols() {
            let col: Vec<f64> = jac.column(j).iter().copied().collect();
            for (i, v) in self.whiten(&col, weights, scales).0.into_iter().enumerate() {
                jz[(i, j)] = v;
            }
        }
        (z, jz)
    }

    pub(super) fn physical(&self, x: &[f64]) -> bool {
        let p = self.full(x);
        p[..3].iter().all(|v| v.is_finite() && *v > 0.0)
            && p[6].abs() <= self.max_offset
            && p.iter().all(|v| v.is_finite())
    }
}

/// The indices of the reference poses inside the wheels' time span, `margin` in from each end
/// for the time offset; an error when fewer than ten blocks would be compared.
fn select_poses(
    recording: &PoseRecording,
    kind: ReferenceKind,
    margin: f64,
) -> Result<Vec<usize>, CalibrationError> {
    let (w0, w1) = (
        recording.wheels[0].time_s,
        recording.wheels[recording.wheels.len() - 1].time_s,
    );
    let selected: Vec<usize> = recording
        .poses
        .iter()
        .enumerate()
        .filter(|(_, p)| p.time_s - margin >= w0 && p.time_s + margin <= w1)
        .map(|(i, _)| i)
        .collect();
    let blocks = match kind {
        ReferenceKind::Absolute => selected.len(),
        ReferenceKind::Relative => selected.len().saturating_sub(1),
    };
    if blocks < 10 {
        return Err(CalibrationError::PoseInput(format!(
            "only {} reference pose(s) fall inside the wheels' time span ({w0:.3}–{w1:.3} s, \
             less {margin:.2} s each side for the time offset; at least 10 are needed): \
             check that both streams are stamped on the same clock (seconds) and that the \
             reference covers the drive{}",
            selected.len(),
            if margin > 0.0 {
                ", or lower --max-time-offset-s"
            } else {
                ""
            },
        )));
    }
    Ok(selected)
}

/// The parameters to fit, in the parameter vector's order.
fn free_params(config: &FitConfig, has_yaw: bool, fit_offset: bool) -> Vec<Param> {
    let mut free = vec![Param::LeftDiameter];
    if !config.tie_diameters {
        free.push(Param::RightDiameter);
    }
    free.push(Param::Wheelbase);
    if config.fit_mounting {
        free.push(Param::SensorX);
        free.push(Param::SensorY);
        if has_yaw {
            free.push(Param::SensorYaw);
        }
    }
    if fit_offset {
        free.push(Param::TimeOffset);
    }
    free
}

/// Windows `[start, end)` over `selected`, each closed once it spans `window_s` seconds of the
/// reference's clock (the last at the end).
fn time_windows(
    recording: &PoseRecording,
    selected: &[usize],
    window_s: f64,
) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = 0;
    for i in 1..=selected.len() {
        let done = i == selected.len()
            || recording.poses[selected[i]].time_s - recording.poses[selected[start]].time_s
                >= window_s;
        if done {
            out.push((start, i));
            start = i;
        }
    }
    out
}

/// A window grows by the next until it holds ten samples, and a short last one joins the window
/// before it: an alignment of a few samples would absorb everything they hold.
fn merge_short_windows(out: Vec<(usize, usize)>) -> Vec<(usize, usize)> {
    let mut merged: Vec<(usize, usize)> = Vec::new();
    for w in out {
        match merged.last_mut() {
            Some(last) if last.1 - last.0 < 10 => last.1 = w.1,
            _ => merged.push(w),
        }
    }
    if merged.len() > 1 && merged[merged.len() - 1].1 - merged[merged.len() - 1].0 < 10 {
        let tail = merged.pop().map_or(0, |t| t.1);
        if let Some(last) = merged.last_mut() {
            last.1 = tail;
        }
    }
    merged
}

/// The reference's motion between consecutive selected samples (relative references).
fn reference_steps(recording: &PoseRecording, selected: &[usize]) -> Vec<Pose2> {
    selected
        .windows(2)
        .map(|k| {
            let (r0, r1) = (&recording.poses[k[0]], &recording.poses[k[1]]);
            r0.pose2().between(&r1.pose2())
        })
        .collect()
}

/// A difference of residual components; yaw components wrap.
pub(super) fn angle_aware_diff(a: f64, b: f64, i: usize, dim: usize) -> f64 {
    if dim == 3 && i % 3 == 2 {
        wrap_angle(a - b)
    } else {
        a - b
    }
}

/// The finite-difference step of a parameter.
pub(super) fn step(param: Param, p: &[f64; PARAMS]) -> f64 {
    match param {
        Param::LeftDiameter | Param::RightDiameter | Param::Wheelbase => 1e-7 * p[param.index()],
        Param::SensorX | Param::SensorY => 1e-6,
        Param::SensorYaw => 1e-6,
        Param::TimeOffset => 1e-5,
    }
}
