use super::*;
use std::cell::RefCell;

/// Two degenerate modes and one single, a candidate vertex where mode 0 moves (along x)
/// and mode 1 does not.
fn toy() -> ModesAtPoisson {
    let mut values = DMatrix::zeros(6, 3);
    values[(0, 0)] = 2.0; // vertex 0, x: mode 0
    values[(4, 2)] = 1.0; // vertex 1, y: mode 2
    ModesAtPoisson {
        theta: vec![1.0, 1.0, 4.0],
        strike: vec![1.0, 1.0, 1.0],
        values,
        lame: (0.0, 0.0),
        coefficients: DMatrix::zeros(0, 3),
        rigid: DMatrix::zeros(0, 0),
        rigid_strike: Vec::new(),
    }
}

#[test]
fn a_lumped_mass_lowers_only_the_mode_that_moves_there() {
    let modes = toy();
    let alpha = 0.1;
    let loaded = loaded_modes(&modes, &[0], alpha);
    // Mode 0: θ/(1 + α·4) exactly (the mass couples nothing else); modes 1 and 2 unchanged.
    let expected = [1.0 / (1.0 + alpha * 4.0), 1.0, 4.0];
    for (got, want) in loaded.iter().zip(expected) {
        assert!((got.0 - want).abs() < 1e-12, "{loaded:?}");
    }
    // Without mass the values are θ.
    let none = loaded_modes(&modes, &[0], 0.0);
    assert!(none
        .iter()
        .zip([1.0, 1.0, 4.0])
        .all(|(g, w)| (g.0 - w).abs() < 1e-12));
}

#[test]
fn loaded_ritz_values_match_a_dense_generalised_solve() {
    // Random SPD coupling: the Cholesky route against det(K − θM) = 0 solved densely.
    let n = 5;
    let mut values = DMatrix::zeros(6, n);
    for (i, x) in values.iter_mut().enumerate() {
        *x = ((i * 37 % 11) as f64 - 5.0) / 7.0;
    }
    let modes = ModesAtPoisson {
        theta: vec![1.0, 1.3, 2.0, 2.2, 3.5],
        strike: vec![0.3, -0.2, 0.5, 0.1, 0.4],
        values,
        lame: (0.0, 0.0),
        coefficients: DMatrix::zeros(0, n),
        rigid: DMatrix::zeros(0, 0),
        rigid_strike: Vec::new(),
    };
    let gram = region_gram(&modes, &[0, 1]);
    let alpha = 0.07;
    let loaded = loaded_modes(&modes, &[0, 1], alpha);
    let m = DMatrix::identity(n, n) + &gram * alpha;
    let k = DMatrix::from_diagonal(&DVector::from_vec(modes.theta.clone()));
    for (theta, _) in &loaded {
        let det = (&k - &m * *theta).determinant();
        let scale = (&k + &m).determinant().abs();
        assert!(det.abs() < 1e-9 * scale, "θ' = {theta}: det {det}");
        assert!(*theta <= 3.5 + 1e-12);
    }
    // Interlacing: adding mass never raises a Ritz value.
    for (l, t) in loaded.iter().zip(&modes.theta) {
        assert!(l.0 <= t + 1e-12);
    }
}

/// The loaded drives (s·y)² with y M-normalised, against a Cholesky factorisation of
/// M + αG per α (the route `RegionProblem` replaced by its eigenbasis of the unloaded pencil),
/// on a basis with a coupled mass matrix (attachment-like columns) and masses from 0 to 16 %.
#[test]
fn loaded_drives_match_a_cholesky_solve_per_mass() {
    let n = 6;
    let mut values = DMatrix::zeros(9, n);
    for (i, x) in values.iter_mut().enumerate() {
        *x = ((i * 29 % 13) as f64 - 6.0) / 5.0;
    }
    let modes = ModesAtPoisson {
        theta: vec![1.0, 1.4, 2.1, 2.5, 3.3, 4.0],
        strike: vec![0.3, -0.2, 0.5, 0.1, 0.4, -0.6],
        values,
        lame: (0.0, 0.0),
        coefficients: DMatrix::zeros(0, n),
        rigid: DMatrix::zeros(0, 0),
        rigid_strike: Vec::new(),
    };
    let region = [0, 2];
    let gram = region_gram(&modes, &region);
    let k = DMatrix::from_diagonal(&DVector::from_vec(modes.theta.clone()));
    let s = DVector::from_vec(modes.strike.clone());
    for alpha in [0.0, 0.01, 0.07, 0.3, 2.0] {
        let got = loaded_modes(&modes, &region, alpha);
        let m = DMatrix::identity(n, n) + &gram * alpha;
        let l = m.cholesky().unwrap().l();
        let li = l.clone().try_inverse().unwrap();
        let eig = SymmetricEigen::new(&li * &k * li.transpose());
        let mut want: Vec<(f64, f64)> = (0..n)
            .map(|j| {
                let y = li.transpose() * eig.eigenvectors.column(j);
                (eig.eigenvalues[j], s.dot(&y).powi(2))
            })
            .collect();
        want.sort_by(|a, b| a.0.total_cmp(&b.0));
        assert_eq!(got.len(), n, "α = {alpha}: {got:?}");
        for (g, w) in got.iter().zip(&want) {
            assert!(
                (g.0 - w.0).abs() < 1e-11 * w.0,
                "α = {alpha}: θ' {g:?} vs {w:?}"
            );
            assert!(
                (g.1 - w.1).abs() < 1e-10,
                "α = {alpha}: drive {g:?} vs {w:?}"
            );
        }
    }
}

/// Lowest `n` eigenvalues of K x = θ M x (M SPD) densely.
fn dense_generalised(k: &DMatrix<f64>, m: &DMatrix<f64>, n: usize) -> Vec<f64> {
    let l = m.clone().cholesky().unwrap().l();
    let li = l.clone().try_inverse().unwrap();
    let a = &li * k * li.transpose();
    let mut v: Vec<f64> = SymmetricEigen::new((&a + a.transpose()) * 0.5)
        .eigenvalues
        .iter()
        .copied()
        .collect();
    v.sort_by(f64::total_cmp);
    v.truncate(n);
    v
}

/// A free chain of `size` DOFs: spring i has moduli (λ_i, μ_i) = `moduli(i)` in K_λ and
/// K_μ, and the diagonal M₁ = 1 + 0.2 (i mod 3). Returns (K_λ, K_μ, M₁).
fn chain(
    size: usize,
    moduli: impl Fn(usize) -> (f64, f64),
) -> (DMatrix<f64>, DMatrix<f64>, DMatrix<f64>) {
    let mut k_lambda = DMatrix::zeros(size, size);
    let mut k_mu = DMatrix::zeros(size, size);
    for i in 0..size - 1 {
        let (kl, km) = moduli(i);
        for (mat, k) in [(&mut k_lambda, kl), (&mut k_mu, km)] {
            mat[(i, i)] += k;
            mat[(i + 1, i + 1)] += k;
            mat[(i, i + 1)] -= k;
            mat[(i + 1, i)] -= k;
        }
    }
    let mass1 = DMatrix::from_diagonal(&DVector::from_iterator(
        size,
        (0..size).map(|i| 1.0 + 0.2 * ((i % 3) as f64)),
    ));
    (k_lambda, k_mu, mass1)
}

/// Attachment vectors of the chain: static responses of K + 10⁻³M₁ to unit loads on DOFs
/// `first..first + 3`, the rigid translation projected out, M₁-normalised.
fn chain_attachments(
    k: &DMatrix<f64>,
    mass1: &DMatrix<f64>,
    rigid: &DMatrix<f64>,
    first: usize,
) -> DMatrix<f64> {
    let mut loads = DMatrix::zeros(k.nrows(), 3);
    for c in 0..3 {
        loads[(first + c, c)] = 1.0;
    }
    let mut attach = (k + mass1 * 1e-3).lu().solve(&loads).unwrap();
    for j in 0..3 {
        let along = (rigid.transpose() * mass1 * attach.column(j))[(0, 0)];
        let column = attach.column(j) - rigid * along;
        let norm = (column.transpose() * mass1 * &column)[(0, 0)].sqrt();
        attach.set_column(j, &(column / norm));
    }
    attach
}

#[test]
fn the_rigid_motion_and_attachment_vectors_bring_the_loaded_ritz_values_to_the_full_solve() {
    // A free "body": a chain of 60 masses and springs with two moduli, K(ν) = a K_λ + b K_μ,
    // M₁ diagonal, one rigid motion (translation). The reduced basis is its first 6 elastic
    // modes at ν, the candidate region DOFs 30..33 ("vertex" 10), a heavy mass there, the
    // strike at DOF 59.
    let size = 60;
    let (k_lambda, k_mu, mass1) = chain(size, |i| {
        (
            1.0 + 0.3 * ((i * 7 % 5) as f64),
            2.0 + 0.5 * ((i * 3 % 4) as f64),
        )
    });
    let (a, b) = crate::eigen::reduced::lame_unit(0.3);
    let k = &k_lambda * a + &k_mu * b;
    let l = mass1.clone().cholesky().unwrap().l();
    let li = l.clone().try_inverse().unwrap();
    let eig = SymmetricEigen::new({
        let x = &li * &k * li.transpose();
        (&x + x.transpose()) * 0.5
    });
    let mut order: Vec<usize> = (0..size).collect();
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    // order[0] is the rigid translation (θ = 0); the basis is the next 6, M₁-orthonormal.
    let n = 6;
    let basis = DMatrix::from_columns(
        &order[1..=n]
            .iter()
            .map(|&i| li.transpose() * eig.eigenvectors.column(i))
            .collect::<Vec<_>>(),
    );
    let theta: Vec<f64> = order[1..=n].iter().map(|&i| eig.eigenvalues[i]).collect();
    let total: f64 = mass1.diagonal().sum();
    let rigid = DMatrix::from_element(size, 1, 1.0 / total.sqrt());
    let values = basis.clone();
    let with_rigid = ModesAtPoisson {
        theta,
        strike: basis.row(size - 1).iter().copied().collect(),
        values,
        lame: (a, b),
        coefficients: DMatrix::identity(n, n),
        rigid: rigid.clone(),
        rigid_strike: vec![rigid[(size - 1, 0)]],
    };
    let without_rigid = ModesAtPoisson {
        rigid: DMatrix::zeros(0, 0),
        rigid_strike: Vec::new(),
        ..with_rigid.clone()
    };
    let region = [10usize];
    // Attachment vectors at the region's DOFs.
    let attach = chain_attachments(&k, &mass1, &rigid, 30);
    let projections = AttachmentProjections {
        cross_lambda: basis.transpose() * &k_lambda * &attach,
        cross_mu: basis.transpose() * &k_mu * &attach,
        cross_mass: basis.transpose() * &mass1 * &attach,
        self_lambda: attach.transpose() * &k_lambda * &attach,
        self_mu: attach.transpose() * &k_mu * &attach,
        self_mass: attach.transpose() * &mass1 * &attach,
        probe_values: DMatrix::zeros(0, 3),
    };
    let extra = Enrichment {
        projections,
        region_values: attach.rows(30, 3).into_owned(),
        strike: attach.row(size - 1).iter().copied().collect(),
    };
    let alpha = 8.0;
    let enriched = loaded_modes_enriched(&with_rigid, &region, &extra, alpha).unwrap();
    let modal = loaded_modes(&with_rigid, &region, alpha);
    let anchored = loaded_modes(&without_rigid, &region, alpha);
    // The full loaded model's elastic values (its rigid translation dropped).
    let mut loaded_mass = mass1.clone();
    for c in 0..3 {
        loaded_mass[(30 + c, 30 + c)] += alpha;
    }
    let full: Vec<f64> = dense_generalised(&k, &loaded_mass, n + 1)[1..].to_vec();
    // The enriched values equal the dense projection on [Φ, A, R] (its rigid value dropped) …
    let u = DMatrix::from_fn(size, n + 4, |r, c| {
        if c < n {
            basis[(r, c)]
        } else if c < n + 3 {
            attach[(r, c - n)]
        } else {
            rigid[(r, 0)]
        }
    });
    let projected = dense_generalised(
        &(u.transpose() * &k * &u),
        &(u.transpose() * &loaded_mass * &u),
        n + 1,
    )[1..]
        .to_vec();
    assert_eq!(enriched.len(), n);
    for (e, p) in enriched.iter().zip(&projected) {
        assert!(
            (e.0 / p - 1.0).abs() < 1e-9,
            "enriched {enriched:?} against projected {projected:?}"
        );
    }
    // … bound the full values from above, below the modal values, and are several times
    // closer to the full solve.
    let (mut modal_error, mut enriched_error) = (0.0_f64, 0.0_f64);
    for ((e, m), f) in enriched.iter().zip(&modal).zip(&full) {
        assert!(
            e.0 >= f * (1.0 - 1e-9) && e.0 <= m.0 * (1.0 + 1e-9),
            "full {f}, enriched {}, modal {}",
            e.0,
            m.0
        );
        modal_error = modal_error.max(m.0 / f - 1.0);
        enriched_error = enriched_error.max(e.0 / f - 1.0);
    }
    assert!(
        modal_error > 1e-2,
        "the test case must be hard for the modes alone: {modal_error}"
    );
    assert!(
        enriched_error < 0.2 * modal_error,
        "enriched error {enriched_error} against modal {modal_error}"
    );
    // Without the rigid motion the basis anchors the body: the first value falls below
    // the full solve's (no bound), which is why the basis carries it.
    assert!(
        anchored[0].0 < full[0] * (1.0 - 1e-3),
        "anchored {} against full {}",
        anchored[0].0,
        full[0]
    );
    // A mismatched enrichment is refused, not misused.
    let wrong = Enrichment {
        strike: vec![0.0; 2],
        ..extra
    };
    assert!(loaded_modes_enriched(&with_rigid, &region, &wrong, alpha).is_none());
}

#[test]
fn re_anchoring_solves_the_attachments_at_the_poisson_ratio_the_search_reaches() {
    // The chain of the test above, its stiffness now depending on ν as a body's does,
    // K(ν) = a(ν) K_λ + b(ν) K_μ, with a reduced space V spanned by the modes at three ν
    // (as `PoissonBasis`), "vertices" of three DOFs, candidate regions at vertices 4, 10
    // and 15. The target is the full solve with 10 % of the mass at vertex 10 and ν = 0.32;
    // the plain match's ν, the first anchor, is 0.05. (On this chain the fixed anchor's
    // search still lands near the true ν; on the bowl it did not, module docs.)
    let size = 60;
    let (k_lambda, k_mu, mass1) = chain(size, |i| {
        (
            0.2 + 1.5 * ((i * 7 % 5) as f64),
            2.0 + 0.5 * ((i * 3 % 4) as f64),
        )
    });
    let total: f64 = mass1.diagonal().sum();
    let stiffness_at = |nu: f64| {
        let (a, b) = crate::eigen::reduced::lame_unit(nu);
        &k_lambda * a + &k_mu * b
    };
    let rigid = DMatrix::from_element(size, 1, 1.0 / total.sqrt());
    // M-orthonormal elastic eigenvectors of (k, m), lowest first (the rigid one dropped).
    let elastic = |k: &DMatrix<f64>, m: &DMatrix<f64>, n: usize| -> (Vec<f64>, DMatrix<f64>) {
        let li = m.clone().cholesky().unwrap().l().try_inverse().unwrap();
        let x = &li * k * li.transpose();
        let eig = SymmetricEigen::new((&x + x.transpose()) * 0.5);
        let mut order: Vec<usize> = (0..eig.eigenvalues.len()).collect();
        order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
        let floor = 1e-9 * eig.eigenvalues.amax();
        let keep: Vec<usize> = order
            .into_iter()
            .filter(|&i| eig.eigenvalues[i] > floor)
            .take(n)
            .collect();
        (
            keep.iter().map(|&i| eig.eigenvalues[i]).collect(),
            DMatrix::from_columns(
                &keep
                    .iter()
                    .map(|&i| li.transpose() * eig.eigenvectors.column(i))
                    .collect::<Vec<_>>(),
            ),
        )
    };
    let n = 6;
    // V: the first n modes at ν = 0.1, 0.25, 0.4, M-orthonormalised (Gram–Schmidt twice).
    let mut columns: Vec<DVector<f64>> = Vec::new();
    for nu in [0.1, 0.25, 0.4] {
        let (_, phi) = elastic(&stiffness_at(nu), &mass1, n);
        for j in 0..n {
            let mut v = phi.column(j).into_owned();
            for _ in 0..2 {
                for q in &columns {
                    let c = (q.transpose() * &mass1 * &v)[(0, 0)];
                    v -= q * c;
                }
            }
            let norm = (v.transpose() * &mass1 * &v)[(0, 0)].sqrt();
            if norm > 1e-8 {
                columns.push(v / norm);
            }
        }
    }
    let space = DMatrix::from_columns(&columns);
    let modes_at = |nu: f64| -> ModesAtPoisson {
        let (theta, z) = elastic(
            &(space.transpose() * stiffness_at(nu) * &space),
            &DMatrix::identity(space.ncols(), space.ncols()),
            n,
        );
        let values = &space * &z;
        ModesAtPoisson {
            theta,
            strike: values.row(size - 1).iter().copied().collect(),
            values,
            lame: crate::eigen::reduced::lame_unit(nu),
            coefficients: z,
            rigid: rigid.clone(),
            rigid_strike: vec![rigid[(size - 1, 0)]],
        }
    };
    let candidates = [4usize, 10, 15];
    let regions: Vec<Vec<usize>> = candidates.iter().map(|&v| vec![v]).collect();
    let anchors_asked = RefCell::new(Vec::<f64>::new());
    let enrich = |r: usize, anchor: f64| -> Option<Rc<Enrichment>> {
        anchors_asked.borrow_mut().push(anchor);
        let k = stiffness_at(anchor);
        let v = regions[r][0];
        let attach = chain_attachments(&k, &mass1, &rigid, 3 * v);
        let projections = AttachmentProjections {
            cross_lambda: space.transpose() * &k_lambda * &attach,
            cross_mu: space.transpose() * &k_mu * &attach,
            cross_mass: space.transpose() * &mass1 * &attach,
            self_lambda: attach.transpose() * &k_lambda * &attach,
            self_mu: attach.transpose() * &k_mu * &attach,
            self_mass: attach.transpose() * &mass1 * &attach,
            probe_values: DMatrix::zeros(0, 3),
        };
        Some(Rc::new(Enrichment {
            projections,
            region_values: attach.rows(3 * v, 3).into_owned(),
            strike: attach.row(size - 1).iter().copied().collect(),
        }))
    };
    // The full loaded solve, as θ' (E/ρ = 1) with drives, and its line frequencies.
    let (density, youngs) = (2700.0_f64, 7e10_f64);
    let two_pi_ln = (2.0 * std::f64::consts::PI).ln();
    let full_solve = |nu: f64, vertex: usize, fraction: f64| -> Vec<(f64, f64)> {
        let mut loaded = mass1.clone();
        for c in 0..3 {
            loaded[(3 * vertex + c, 3 * vertex + c)] += fraction * total;
        }
        let (theta, phi) = elastic(&stiffness_at(nu), &loaded, n);
        theta
            .into_iter()
            .enumerate()
            .map(|(k, t)| (t, phi[(size - 1, k)].powi(2)))
            .collect()
    };
    let (truth_nu, truth_fraction) = (0.32, 0.10);
    let target: Vec<f64> = full_solve(truth_nu, 10, truth_fraction)
        .iter()
        .map(|p| 0.5 * p.0.ln() + 0.5 * (youngs / density).ln() - two_pi_ln)
        .collect();
    let neighbours = |r: usize| vec![r];
    let problem = LoadedMatchProblem {
        target_ln_f: &target,
        ceiling_ln_f: f64::INFINITY,
        density,
        volume: total,
        regions: &regions,
        coarse: &[0, 1, 2],
        neighbours: &neighbours,
        plain_youngs: youngs,
        enrichment: Some(&enrich),
        anchor_poisson: 0.05,
    };
    let run = |rounds: usize| {
        anchors_asked.borrow_mut().clear();
        let settings = LoadedMatchSettings {
            poisson_bounds: (0.0, 0.45),
            coarse_poisson_step: 0.02,
            reanchor_rounds: rounds,
            ..Default::default()
        };
        let found = loaded_line_candidates(&problem, &modes_at, &settings, 3, &Alone)
            .unwrap()
            .into_iter()
            .find(|c| c.region == 1)
            .expect("a candidate at the true site");
        // The answer judged as the caller judges it, by a full solve at its ν, site and mass.
        let checked = scale_fit(
            &target,
            f64::INFINITY,
            &full_solve(found.poisson, 10, found.mass_kg / (density * total)),
            density,
            found.youngs,
            0.02,
            &settings,
        )
        .0;
        (found, checked, anchors_asked.borrow().clone())
    };
    let (fixed, fixed_checked, fixed_anchors) = run(0);
    let (moved, moved_checked, moved_anchors) = run(3);
    // Without re-anchoring every enrichment is at the plain ν; with it, the answer's
    // attachment vectors are solved within one anchor step of the ν it reached.
    assert!(
        fixed_anchors.iter().all(|&a| a == 0.05) && fixed.anchor_poisson == 0.05,
        "{fixed:?}"
    );
    assert!(
        moved_anchors.iter().any(|&a| a != 0.05),
        "{moved_anchors:?}"
    );
    assert!(
        (moved.anchor_poisson - moved.poisson).abs() <= 0.005 + 1e-12,
        "{moved:?}"
    );
    // Far from its anchor the enriched model misjudges the answer (here 24 times the full
    // solve's distance); anchored where the search ends, its distance is the full solve's
    // within a factor 2, so the search compares configurations by a faithful model.
    assert!(
        (moved.poisson - truth_nu).abs() < 0.01,
        "re-anchored {moved:?}"
    );
    let faithful = |ritz: f64, full: f64| (ritz / full).ln().abs() < 2f64.ln();
    assert!(
        faithful(moved.distance, moved_checked),
        "re-anchored: Ritz {:.3e} against full {moved_checked:.3e}",
        moved.distance
    );
    assert!(
        !faithful(fixed.distance, fixed_checked),
        "the test needs a misled fixed anchor: Ritz {:.3e} against full {fixed_checked:.3e}",
        fixed.distance
    );
}

#[test]
fn the_search_recovers_a_planted_mass_and_scale() {
    // Modes independent of ν; candidate vertex 0 moves modes 0 and 2, vertex 1 mode 1.
    let n = 6;
    let mut values = DMatrix::zeros(6, n);
    // Mass-normalised values scale as 1/√V (V = 10⁻⁴ m³): αG ≈ 0.1 at 4 % of the mass.
    values[(0, 0)] = 150.0;
    values[(0, 2)] = 80.0;
    values[(4, 1)] = 120.0;
    values[(3, 4)] = 50.0;
    let theta: Vec<f64> = [1.0_f64, 1.0, 2.6, 2.6, 5.1, 7.3]
        .iter()
        .map(|t| t * 1e7)
        .collect();
    let modes = ModesAtPoisson {
        theta,
        strike: vec![1.0; n],
        values,
        lame: (0.0, 0.0),
        coefficients: DMatrix::zeros(0, n),
        rigid: DMatrix::zeros(0, 0),
        rigid_strike: Vec::new(),
    };
    let (density, volume) = (2700.0_f64, 1e-4);
    let truth_youngs = 7e10_f64;
    let regions = vec![vec![0], vec![1]];
    let alpha = 0.04 * volume;
    let two_pi_ln = (2.0 * std::f64::consts::PI).ln();
    let target: Vec<f64> = loaded_modes(&modes, &regions[0], alpha)
        .iter()
        .map(|p| 0.5 * p.0.ln() + 0.5 * (truth_youngs / density).ln() - two_pi_ln)
        .collect();
    let neighbours = |_r: usize| vec![0, 1];
    let problem = LoadedMatchProblem {
        target_ln_f: &target,
        ceiling_ln_f: f64::INFINITY,
        density,
        volume,
        regions: &regions,
        coarse: &[0, 1],
        neighbours: &neighbours,
        plain_youngs: 0.9 * truth_youngs,
        enrichment: None,
        anchor_poisson: 0.25,
    };
    let settings = LoadedMatchSettings {
        poisson_bounds: (0.2, 0.3),
        ..Default::default()
    };
    let found = loaded_line_match(&problem, &|_nu| modes.clone(), &settings).unwrap();
    assert_eq!(found.region, 0, "{found:?}");
    assert!(found.distance < 1e-4, "{found:?}");
    assert!(
        (found.mass_kg / (density * volume) - 0.04).abs() < 0.003,
        "{found:?}"
    );
    assert!(
        (found.youngs / truth_youngs - 1.0).abs() < 2e-3,
        "{found:?}"
    );
    // The plain pattern (no mass) cannot match the split.
    let plain: Vec<f64> = modes.theta.iter().map(|t| 0.5 * t.ln()).collect();
    let c = 0.5 * (truth_youngs / density).ln() - two_pi_ln;
    assert!(capped_nearest(&target, &plain, c, 0.02) > 1e-3);
}

/// Two parts that swap their numbers through shared memory, as two ranks would.
struct Pair {
    part: usize,
    exchange: std::sync::Arc<(std::sync::Mutex<Vec<Vec<f64>>>, std::sync::Barrier)>,
}

impl Share for Pair {
    fn part(&self) -> (usize, usize) {
        (self.part, 2)
    }
    fn gather(&self, local: &[f64]) -> Vec<f64> {
        let (slots, barrier) = &*self.exchange;
        slots.lock().unwrap()[self.part] = local.to_vec();
        barrier.wait();
        let all = slots.lock().unwrap().concat();
        // Nobody writes the next round before both have read this one.
        barrier.wait();
        all
    }
}

#[test]
fn two_parts_find_what_one_finds_bit_for_bit() {
    // Three sites that all move the split modes, so that the coarse regions, the seeds and
    // the fine passes all have close competitors; the modes drift with ν.
    let n = 6;
    let mut values = DMatrix::zeros(9, n);
    values[(0, 0)] = 150.0;
    values[(0, 2)] = 80.0;
    values[(4, 1)] = 120.0;
    values[(3, 4)] = 50.0;
    values[(6, 0)] = 90.0;
    values[(7, 1)] = 95.0;
    values[(8, 3)] = 60.0;
    let base: Vec<f64> = [1.0_f64, 1.0, 2.6, 2.6, 5.1, 7.3]
        .iter()
        .map(|t| t * 1e7)
        .collect();
    let modes_at = |nu: f64| ModesAtPoisson {
        theta: base
            .iter()
            .enumerate()
            .map(|(k, t)| t * (1.0 + (k as f64 - 2.0) * 0.3 * (nu - 0.25)))
            .collect(),
        strike: vec![1.0; n],
        values: values.clone(),
        lame: (0.0, 0.0),
        coefficients: DMatrix::zeros(0, n),
        rigid: DMatrix::zeros(0, 0),
        rigid_strike: Vec::new(),
    };
    let (density, volume, youngs) = (2700.0_f64, 1e-4, 7e10_f64);
    let regions = vec![vec![0], vec![1], vec![2], vec![0, 2]];
    let two_pi_ln = (2.0 * std::f64::consts::PI).ln();
    let target: Vec<f64> = loaded_modes(&modes_at(0.27), &regions[2], 0.05 * volume)
        .iter()
        .map(|p| 0.5 * p.0.ln() + 0.5 * (youngs / density).ln() - two_pi_ln)
        .collect();
    let settings = LoadedMatchSettings {
        poisson_bounds: (0.15, 0.35),
        coarse_poisson_step: 0.01,
        ..Default::default()
    };
    let run = |share: &dyn Share| {
        let neighbours = |r: usize| match r {
            0 | 3 => vec![r, 3 - r, 2],
            _ => vec![r, 3],
        };
        let problem = LoadedMatchProblem {
            target_ln_f: &target,
            ceiling_ln_f: f64::INFINITY,
            density,
            volume,
            regions: &regions,
            coarse: &[0, 1, 2, 3],
            neighbours: &neighbours,
            plain_youngs: 0.9 * youngs,
            enrichment: None,
            anchor_poisson: 0.25,
        };
        let found = loaded_line_candidates(&problem, &modes_at, &settings, 3, share).unwrap();
        format!("{found:?}")
    };
    let alone = run(&Alone);
    let exchange = std::sync::Arc::new((
        std::sync::Mutex::new(vec![Vec::new(), Vec::new()]),
        std::sync::Barrier::new(2),
    ));
    let shared: Vec<String> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..2)
            .map(|part| {
                let share = Pair {
                    part,
                    exchange: exchange.clone(),
                };
                let run = &run;
                scope.spawn(move || run(&share))
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert!(alone.contains("region: 2"), "{alone}");
    assert_eq!(shared[0], alone);
    assert_eq!(shared[1], alone);
}

#[test]
fn bad_input_is_an_error() {
    let modes = toy();
    let regions = vec![vec![0]];
    let neighbours = |_r: usize| vec![0];
    let problem = LoadedMatchProblem {
        target_ln_f: &[],
        ceiling_ln_f: 10.0,
        density: 2700.0,
        volume: 1e-4,
        regions: &regions,
        coarse: &[0],
        neighbours: &neighbours,
        plain_youngs: 7e10,
        enrichment: None,
        anchor_poisson: 0.25,
    };
    assert_eq!(
        loaded_line_match(
            &problem,
            &|_nu| modes.clone(),
            &LoadedMatchSettings::default()
        )
        .err(),
        Some(LoadedMatchError::NoTargetModes)
    );
    let problem = LoadedMatchProblem {
        target_ln_f: &[7.0],
        coarse: &[],
        ..problem
    };
    assert_eq!(
        loaded_line_match(
            &problem,
            &|_nu| modes.clone(),
            &LoadedMatchSettings::default()
        )
        .err(),
        Some(LoadedMatchError::NoRegion)
    );
}

#[test]
fn split_pairs_merge_once_each_and_the_closer_neighbour_first() {
    let mut lines = vec![(0.1, 1.0), (0.0, 2.0), (0.001, 5.0)];
    merge_split_pairs(&mut lines, 0.015);
    assert_eq!(lines.len(), 2);
    assert!((lines[0].0 - 0.0005).abs() < 1e-12 && lines[0].1 == 5.0);
    assert_eq!(lines[1], (0.1, 1.0));
    // Three within the tolerance: the middle one pairs with its closer neighbour, the first
    // stays alone.
    let mut three = vec![(0.0, 1.0), (0.010, 1.0), (0.012, 1.0)];
    merge_split_pairs(&mut three, 0.015);
    assert_eq!(three.len(), 2);
    assert_eq!(three[0].0, 0.0);
    assert!((three[1].0 - 0.011).abs() < 1e-12);
    // Four within it: two pairs, never a chain.
    let mut four = vec![(0.0, 1.0), (0.004, 1.0), (0.008, 1.0), (0.012, 1.0)];
    merge_split_pairs(&mut four, 0.015);
    assert_eq!(four.len(), 2);
    // Apart by more than the tolerance: untouched.
    let mut apart = vec![(0.0, 1.0), (0.02, 1.0)];
    merge_split_pairs(&mut apart, 0.015);
    assert_eq!(apart.len(), 2);
}

/// A model that splits its pair as the recording's is split gains on the raw distance but
/// not on the split-free one; a model that moves a lone mode onto its recorded line gains on
/// both.
#[test]
fn the_split_free_distance_forgives_splits_and_not_shifts() {
    let density: f64 = 2700.0;
    let youngs = 7e10;
    let two_pi_ln = (2.0 * std::f64::consts::PI).ln();
    let c = 0.5 * (youngs / density).ln() - two_pi_ln;
    // Recorded: a pair split by 0.6 % about 1 kHz, a lone mode at 2.5 kHz.
    let target = vec![1000f64.ln() - 0.003, 1000f64.ln() + 0.003, 2500f64.ln()];
    let ceiling = 3000f64.ln();
    // θ for E/ρ = 1 of a line at ln f = x: (x − c) doubled, exponentiated.
    let theta = |x: f64| (2.0 * (x - c)).exp();
    let degenerate = vec![
        (theta(1000f64.ln()), 1.0),
        (theta(1000f64.ln()), 1.0),
        (theta(2500f64.ln()), 1.0),
    ];
    let split = vec![
        (theta(1000f64.ln() - 0.003), 1.0),
        (theta(1000f64.ln() + 0.003), 1.0),
        (theta(2500f64.ln()), 1.0),
    ];
    let lone_off = vec![
        (theta(1000f64.ln()), 1.0),
        (theta(1000f64.ln()), 1.0),
        (theta(2500f64.ln() + 0.01), 1.0),
    ];
    let settings = LoadedMatchSettings::default();
    let raw = |m: &[(f64, f64)]| scale_fit(&target, ceiling, m, density, youngs, 0.02, &settings).0;
    let free = |m: &[(f64, f64)]| {
        split_free_fit(&target, ceiling, m, density, youngs, 0.02, &settings, 0.015).0
    };
    assert!(raw(&split) < 1e-4, "{}", raw(&split));
    assert!(raw(&degenerate) > 1e-3, "{}", raw(&degenerate));
    assert!(free(&split) < 1e-4 && free(&degenerate) < 1e-4);
    // The lone mode 1 % off: the scale shares it out, but no merging forgives it.
    assert!(free(&lone_off) > 2e-3, "{}", free(&lone_off));
}

/// The plain model's split-free distance is taken at the ν that places the centres best: a ν
/// that a full match chose with the splits weighed leaves the centres off, and the search
/// over ν finds the one that puts them back (seed 419 case 008 in kind: split-free 3.58·10⁻³
/// at the match's ν, 2.04·10⁻³ at the best).
#[test]
fn the_split_free_distance_over_poisson_finds_the_nu_that_places_the_centres() {
    let density: f64 = 2400.0;
    let youngs = 7.5e10;
    let two_pi_ln = (2.0 * std::f64::consts::PI).ln();
    let c = 0.5 * (youngs / density).ln() - two_pi_ln;
    let theta = |x: f64| (2.0 * (x - c)).exp();
    // A model whose pair centre and lone mode move apart with ν (ln f per unit ν: −0.2 and
    // +0.3), as a shell's bending and breathing modes do.
    let centres = |nu: f64| {
        (
            1500f64.ln() - 0.2 * (nu - 0.22),
            4000f64.ln() + 0.3 * (nu - 0.22),
        )
    };
    let spectrum_at = |nu: f64| {
        let (pair, lone) = centres(nu);
        vec![(theta(pair), 1.0), (theta(pair), 1.0), (theta(lone), 1.0)]
    };
    // Recorded at ν = 0.22 with the pair split by 1 % about its centre.
    let (pair, lone) = centres(0.22);
    let target = vec![pair - 0.005, pair + 0.005, lone];
    let ceiling = 6000f64.ln();
    let settings = LoadedMatchSettings::default();
    let search = |nus: &[f64]| {
        split_free_over_poisson(
            &target,
            ceiling,
            spectrum_at,
            nus,
            density,
            youngs,
            0.02,
            &settings,
            0.03,
        )
    };
    let (at_wrong, nu_wrong) = search(&[0.17]);
    assert_eq!(nu_wrong, 0.17);
    assert!(at_wrong > 2e-3, "{at_wrong}");
    let grid: Vec<f64> = std::iter::once(0.17)
        .chain((0..=120).map(|i| 0.1 + 0.0025 * i as f64))
        .collect();
    let (best, nu) = search(&grid);
    assert!((nu - 0.22).abs() < 1.5e-3, "ν = {nu}");
    assert!(best < 1e-4 && best < at_wrong, "{best} against {at_wrong}");
    // The match's own ν comes first, so the result is never worse than at it.
    let (on_tie, nu_tie) = search(&[0.22, 0.22]);
    assert_eq!(nu_tie, 0.22);
    assert!(on_tie <= best + 1e-12);
}
