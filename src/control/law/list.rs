//! THE list of surge laws. A new law is one file under `control/laws/` (its state machine,
//! its settings, its [`LawSpec`](super::api::LawSpec)) plus one line here; the law's id, the
//! registry and the DBC value table, the dispatch ([`super::Law`]), the `[controller.<section>]`
//! of the settings and the names `sim` and `check-config` accept all come from this list.
//!
//! One line per law, in code order:
//!
//! ```text
//! Id  code  "name"  scope  type (below crate::control),  (settings);
//! ```
//!
//! - `scope`: `daemon` (offered everywhere) or `sim` (simulation and benchmarks only: not in
//!   [`LawId::ALL`](super::api::LawId::ALL), the bus or the DBC value table);
//! - `(settings)`: `(section: Type)` for a law with its own `[controller.<section>]`,
//!   `(section)` for one built from another law's section, `()` for none.
//!
//! This file imports nothing: it is a list of tokens the other files expand
//! (`laws!(callback)`).

/// Call `$then!` with the list of laws.
macro_rules! laws {
    ($then:ident) => {
        $then! {
            None             0   "none"               daemon  laws::none::NoLaw,                          ();
            RecyclePi        1   "recycle-pi"         daemon  laws::recycle_pi::RecyclePi,                (recycle_pi: laws::recycle_pi::RecyclePiConfig);
            RecycleFl        2   "recycle-fl"         daemon  laws::recycle_fl::RecycleFl,                (recycle_fl: laws::recycle_fl::RecycleFlConfig);
            DriveTorque      3   "drive-torque"       daemon  laws::drive_torque::DriveTorque,            (drive_torque: laws::drive_torque::DriveTorqueConfig);
            Ccv              4   "ccv"                daemon  laws::ccv::Ccv,                             (ccv: laws::ccv::CcvConfig);
            ThrottleBackstep 5   "throttle-backstep"  daemon  laws::throttle_backstep::ThrottleBackstep,  (throttle_backstep: laws::throttle_backstep::ThrottleBackstepConfig);
            Robust           6   "robust"             daemon  laws::robust::Robust,                       (robust: laws::robust::RobustConfig);
            TipSliding       7   "tip-sliding"        daemon  laws::tip_sliding::TipSliding,              (tip_sliding: laws::tip_sliding::TipSlidingConfig);
            BaselinePi       255 "baseline-pi"        sim     laws::baseline_pi::BaselinePi,              (recycle_pi);
        }
    };
}
pub(crate) use laws;
