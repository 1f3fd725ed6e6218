//! Issue 2 acceptance: the Jacobian's eigenvalues agree with simulation. Right of the peak they
//! are in the left half plane; left of the peak, where the compressor slope is steeper than the
//! throttle's (seed 001 §2.3.5 eq. 2.17; seed 003 Lemma 1 / Routh–Hurwitz), they are not, and a
//! simulation started there leaves the equilibrium.

use crate::common;

use antisurge::control::LawId;
use antisurge::plant::{PlantInputs, SimPlant};

fn inputs(plant: &antisurge::sim::case::PlantCase, throttle: f64) -> PlantInputs {
    let init = plant.file.initial;
    PlantInputs {
        throttle_process: throttle,
        recycle_manual: init.recycle_valve,
        feed: init.feed,
        ..PlantInputs::default()
    }
}

#[test]
fn right_of_peak_is_stable_left_of_peak_is_not() {
    for stem in common::PLANTS {
        let plant = common::plant(stem);
        let p = SimPlant::new(&plant, &inputs(&plant, 0.6)).expect("plant");
        let right = p
            .operating_points(&inputs(&plant, 0.6))
            .pop()
            .expect("eq at 60 %");
        assert!(right.compressor_slope < 0.0, "{stem}");
        assert!(right.stable(), "{stem}: {:?}", right.eigenvalues);
        let left = p
            .operating_points(&inputs(&plant, 0.2))
            .pop()
            .expect("eq at 20 %");
        assert!(
            left.compressor_slope > 0.0,
            "{stem}: 20 % should be left of the peak"
        );
        assert!(
            !left.stable(),
            "{stem}: left of peak reported stable: {:?}",
            left.eigenvalues
        );
    }
}

#[test]
fn routh_hurwitz_agrees_with_eigenvalues_on_the_spool_model() {
    // seed 003 eq. 17–20 for the uncontrolled spool model (constant torque τ0 = Γ at the
    // equilibrium), evaluated with the plant's own parameters, against the numerical
    // eigenvalues of the same equilibrium
    let plant = common::plant("liaw2004_spool");
    let sp = plant.file.spool.expect("spool");
    let p = SimPlant::new(&plant, &inputs(&plant, 0.6)).expect("plant");
    let SimPlant::Spool(s) = &p else { panic!() };
    let (mut n_stable, mut n_unstable) = (0, 0);
    for throttle in [0.9, 0.6, 0.5, 0.45, 0.4, 0.3, 0.2, 0.1] {
        for x in s.equilibria(throttle, s.x[0]) {
            let (w, phi, psi) = (x[0], x[1], x[2]);
            let mp = s.psi_c(phi, w);
            let gamma = sp.gamma_max * throttle;
            // Γ = σ φ ω̃ ; F = γ √ψ
            let dg_dw = sp.torque_coefficient * phi;
            let dg_dphi = sp.torque_coefficient * w;
            let df_dpsi = gamma / (2.0 * psi.sqrt());
            let (a, b, c) = (sp.a_bar, sp.b_bar, sp.c_bar);
            let c1 = a * dg_dw - b * mp.d_dflow + c * df_dpsi; // eq. 18
            let c2 = b * c + a * b * mp.d_domega * dg_dphi
                - a * b * dg_dw * mp.d_dflow
                - b * c * mp.d_dflow * df_dpsi
                + a * c * dg_dw * df_dpsi; // eq. 19
            let c3 = a
                * b
                * c
                * (dg_dw + mp.d_domega * dg_dphi * df_dpsi - dg_dw * mp.d_dflow * df_dpsi); // eq. 20
            let routh_stable = c1 > 0.0 && c3 > 0.0 && c1 * c2 > c3; // Lemma 1
            let mut q = s.clone();
            q.x = x;
            q.hold_inputs(sp.torque_coefficient * phi * w, 0.0, throttle);
            let abscissa = antisurge::plant::analysis::spectral_abscissa(&q, &x);
            assert_eq!(
                routh_stable,
                abscissa < 0.0,
                "throttle {throttle}, φ = {phi}: Routh–Hurwitz {routh_stable}, abscissa {abscissa}"
            );
            if routh_stable {
                n_stable += 1;
            } else {
                n_unstable += 1;
            }
        }
    }
    assert!(
        n_stable >= 3 && n_unstable >= 3,
        "{n_stable} stable, {n_unstable} unstable"
    );
}

#[test]
fn simulation_started_left_of_the_peak_leaves_it() {
    // start at the unstable equilibrium at 20 % and nudge the throttle by 0.1 %-point: the
    // simulation must depart (surge), as the positive real part predicts (an exact fixed point
    // has nothing to grow from, hence the nudge)
    for stem in ["bohagen2007_plenum", "sanadgol2006_tip", "liaw2004_spool"] {
        let plant = common::plant(stem);
        let p = SimPlant::new(&plant, &inputs(&plant, 0.2));
        // SimPlant::new picks the rightmost steady state; at 20 % the only one is unstable
        let p = p.expect("plant");
        let m0 = p.truth().m_kg_s;
        let sc = common::scenario_text(
            "name='nudge20'\ndescription='d'\nduration_s=8\n[initial]\nthrottle=0.2\n[[event]]\nat_s=1\nstep={signal='throttle', to=0.199}\n",
        );
        let r = common::simulate(&plant, &sc, LawId::None);
        assert!(
            r.summary.surge_cycles > 0 || r.summary.flow_reversal,
            "{stem}: started at unstable m = {m0}, summary {:#?}",
            r.summary
        );
    }
}
