//! The catalogue on evidence saved by `diagnose` from recordings of generator 2 (the
//! independent benchmark generator, `scripts/bench/gen2`): the `catalogue_input` of spent
//! cases' reports (`tests/data/diagnose/`), each replayed with the settings its run used.
//! Both are cups with four groups of modes, the fewest on which a contact duration can be
//! tested beside one microphone's gain and tilt.
//!
//! - Seed 311 case 022 is a uniform-shift control (E told 8 % low, no effect concealed; two
//!   microphones, one held out). Its two best-measured levels (σ 0.3 %) can be threaded
//!   exactly by a contact's knee with the gain and the tilt; without the level model floor
//!   (`LEVEL_MODEL_FLOOR`) the amplitude floors fell to zero in that fit and it was accepted
//!   at ΔBIC 25.6.
//! - Seed 283 case 006 has a concealed 0.21 ms half-sine contact (three microphones,
//!   recorded as a pressure): the floor must not take that one away.
//! - Seed 307 case 018 is a plate under Rayleigh damping in a short room (T60 0.34 s, more
//!   reverberant than direct energy; seven microphones, recorded as a velocity). The room
//!   holds every pole decaying faster than 11.9 1/s, so the decay rows left are those
//!   measured below it, the upper ones lowest; read as ordinary rows they bent Rayleigh's
//!   law into a power law (ΔBIC 8.3). Read as truncated at the room's rate
//!   (`ModeTable::decay_ceiling`) they do not.
//! - Seed 307 case 022 is a uniform-shift control on a bar (two microphones, recorded as an
//!   acceleration) with six level rows on the fit microphone. Profiled from those rows
//!   alone, the amplitude floor fell from 0.29 to zero when a contact's null threaded them
//!   beside the channel's gain and tilt, and the contact was named at ΔBIC 8.9. With the
//!   floors' prior (a level is ordinarily ±50 % off, `ORDINARY_LEVEL_SPREAD`) it is not.
//! - Calibration set 9103 case 000 is a cup struck with a 0.32 ms half-sine contact (two
//!   microphones, recorded as a velocity), whose levels scatter by 0.72 about the baseline.
//!   Profiled from the table alone that floor made the contact's fall count for little
//!   (ΔBIC 2.5); with the prior it is named.
//! - The real bowl (the main job's evidence, `bowl_real_strike_8mics.json`): which of its
//!   poles are its lowest partial's, at any weight of the floors' prior.

use diffsound::diagnose::catalogue::{self, CatalogueSettings, Evidence};
use std::path::Path;

fn replay(file: &str) -> catalogue::CatalogueReport {
    replay_with(file, |_| {})
}

/// `file` replayed with its run's settings as `adjust` leaves them.
fn replay_with(file: &str, adjust: impl Fn(&mut CatalogueSettings)) -> catalogue::CatalogueReport {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/diagnose")
        .join(file);
    let text = std::fs::read_to_string(&path).expect("saved evidence");
    let input: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    let evidence: Evidence = serde_json::from_value(input["evidence"].clone()).expect("evidence");
    let mut settings: CatalogueSettings =
        serde_json::from_value(input["settings"].clone()).expect("settings");
    adjust(&mut settings);
    catalogue::diagnose(&evidence, &settings).expect("catalogue")
}

fn accepted(report: &catalogue::CatalogueReport) -> Vec<&str> {
    report.accepted.iter().map(|a| a.name.as_str()).collect()
}

/// No contact duration accepted.
fn no_contact(report: &catalogue::CatalogueReport) {
    assert!(
        !accepted(report).contains(&"contact_duration"),
        "{:#?}",
        report.accepted
    );
}

/// A contact duration fitted and judged (a ΔBIC), and not accepted: the test is of the
/// criterion, not of the screen.
fn contact_judged_and_rejected(report: &catalogue::CatalogueReport) {
    no_contact(report);
    let contact = report
        .rejected
        .iter()
        .find(|r| r.name == "contact_duration")
        .expect("contact duration judged");
    assert!(contact.delta_bic.is_some(), "{contact:#?}");
}

/// A contact duration accepted.
fn contact_named(report: &catalogue::CatalogueReport) {
    assert!(
        accepted(report).contains(&"contact_duration"),
        "{:#?}\n{:#?}",
        report.accepted,
        report.rejected
    );
}

#[test]
fn a_uniform_shift_on_a_cup_with_four_groups_of_modes_is_not_read_as_a_contact() {
    let file = "gen2_seed311_case022_uniform_shift_cup_2mics.json";
    no_contact(&replay(file));
    // The level model floor alone, without the floors' prior (whose floors leave the
    // contact's screen nothing to propose here): the contact is fitted and judged, not
    // skipped, so the test is of the criterion.
    contact_judged_and_rejected(&replay_with(file, |s| s.level_prior_rows = 0.0));
}

#[test]
fn a_true_contact_on_a_cup_with_four_groups_of_modes_is_still_named() {
    contact_named(&replay("gen2_seed283_case006_contact_cup_3mics.json"));
}

#[test]
fn a_plate_in_a_short_room_is_not_given_a_damping_law_by_the_rooms_censoring() {
    let report = replay("gen2_seed307_case018_room_plate_7mics.json");
    let names = accepted(&report);
    assert!(names.contains(&"reverb_noise"), "{:#?}", report.accepted);
    assert!(
        !names.contains(&"non_rayleigh_damping"),
        "{:#?}",
        report.accepted
    );
    let held = report
        .matching
        .room_held
        .as_ref()
        .expect("the room holds poles");
    assert!(!held.frequencies_hz.is_empty(), "{held:?}");
}

#[test]
fn a_uniform_shift_on_a_bar_with_six_level_rows_is_not_read_as_a_contact() {
    contact_judged_and_rejected(&replay("gen2_seed307_case022_uniform_shift_bar_2mics.json"));
}

#[test]
fn a_contact_on_a_cup_whose_levels_scatter_widely_is_named() {
    contact_named(&replay("gen2_seed9103_case000_contact_cup_2mics.json"));
}

/// The real bowl's evidence (`bowl_real_strike_8mics.json`: the main job's diagnosis, four
/// microphones fitted and four held out), replayed at several weights of the amplitude
/// floors' prior. Its lowest partial must be its beating pair, the two 3.1 1/s poles at
/// 1681.2 and 1684.2 Hz, and the pair, the damping law and the room must be named, with the
/// held-out error down by at least 10 %. The pole choice weighs the same likelihood as the
/// effects; a greedy choice of poles (a beam of one) sends that partial to 1684/1687 Hz at
/// every weight from 2 up, and the pair and the damping law go unnamed.
#[test]
fn the_real_bowls_lowest_partial_is_its_beating_pair_at_any_weight_of_the_floors_prior() {
    for weight in [0.0, 2.0, 4.0, 8.0] {
        let report = replay_with("bowl_real_strike_8mics.json", |s| {
            s.level_prior_rows = weight
        });
        let lowest: Vec<f64> = report
            .matching
            .pairs
            .iter()
            .filter(|p| p.cluster == 0)
            .map(|p| p.observed_hz)
            .collect();
        assert!(
            lowest.len() == 2
                && (lowest[0] - 1681.2).abs() < 0.1
                && (lowest[1] - 1684.2).abs() < 0.1,
            "weight {weight}: lowest partial at {lowest:?}"
        );
        let names = accepted(&report);
        for effect in ["beating_pair", "non_rayleigh_damping", "reverb_noise"] {
            assert!(
                names.contains(&effect),
                "weight {weight}: {effect} not named: {names:?}"
            );
        }
        let before = report.baseline.held_out_error.expect("held out");
        let after = report.final_model.held_out_error.expect("held out");
        assert!(
            after < 0.9 * before,
            "weight {weight}: held-out error {before} → {after}"
        );
    }
}
