//! The catalogue of missing physics: where simulation and recording differ, which physics
//! the model left out, whether adding it is worth its parameters.
//!
//! Input ([`Evidence`]): modes extracted from a recording (frequency, decay rate, amplitude
//! per channel, each with its standard deviation; optionally the frequency of an early and a
//! late stretch of each decay), the same for held-out data (other microphones or another time
//! span of the same strike), the simulated modes at the fitted material with a few features
//! per mode (strike drive, energy at a candidate support region, |φ|² at a candidate
//! added-mass region, near-degenerate cluster id, optionally |acoustic transfer| per
//! microphone), and optionally the energy envelopes of the residual (recording − modal
//! resynthesis) per band. [`diagnose`] matches the modes, fits the baseline model, tries
//! every effect of the catalogue, keeps those that pay for their parameters and improve the
//! held-out fit, and returns a [`CatalogueReport`].
//!
//! # Matching
//!
//! In ln f, after a global frequency scale s found by a robust search over all pairings; one
//! to one by increasing distance within `match_tolerance` (default 0.04, i.e. 4 %); a
//! cluster of near-degenerate simulated modes may take one observed mode (unresolved; it
//! stands for the whole cluster, drive √Σ drive², features drive²-weighted) or two (a split
//! pair within `max_pair_split`, default 3 %, each with drive √Σ drive² / √2); so may a
//! single simulated mode. A split pair whose observed split agrees with its two members'
//! simulated split within `own_member_split_z` (default 3) σ, σ as for the split row, stands
//! instead for its own members, the lower observed mode for the lower member: the object
//! splits the pair as the mesh does, so it is the mesh's asymmetry that fixes the two mode
//! shapes, and drive, support and mass weights and transfer are each member's own
//! ([`own_members`]). Pooled, the blind benchmark's radiation case 017 (three such pairs)
//! saw its microphone pattern correlate 0.26 with ln |transfer| instead of 0.9999. A pooled
//! pair keeps the pooled drive and transfer. When the beating-pair screen judges it the
//! object's split under the baseline (a simulated cluster of two or more modes, like decays,
//! centred on its cluster, not a glide, replicated in the held-out recordings), each of its
//! modes then takes the support and mass weights of the member it is predicted at: those
//! weights are the region's principal values in frequency order
//! (`evidence::cluster_region_energies`), so a mass or a support predicts the split it makes
//! instead of leaving it to a free beating pair. Pairs the screen sets aside keep the pooled
//! weights, so a mass cannot be credited with a split that a room or a glide made.
//!
//! *How far a pair may split.* 3 %: what splits a degenerate pair need not be small. A support
//! presses on one member of each pair, and its spring raises that member by k_s|φ|²/(2λ), most
//! at the lowest pairs: generator 2's tubes on a rail split their lowest pair, near 2.4 kHz, by
//! 1.39 %, 1.65 % and 2.1 % (spent seeds 281 case 011, 271 case 001, 307 case 021) and the
//! pairs above by 0.17–0.3 %. Within 1.5 % (the default until then) the upper member of the
//! two wider ones was left unmatched, with the decay rate that showed the support damping it
//! (11.33 against 9.08 1/s, to 0.1 %), and the free splits of the pairs above took the case.
//! Replayed on the saved evidence of 330 spent cases and the real bowl, 2.5 %, 3 % and 4 %
//! changed the same one verdict (271 case 001, to the support) and no other.
//!
//! Observed frequencies are compared at their undamped value
//! f₀ = √(f² + (d/2π)²). A pole more than `faint_pole_db` (40 dB) below another within
//! `max_pair_split` is never a partial of its own, only an extra pole of the partial beside it
//! (a room's or the extraction's residue around a loud partial). Unmatched modes on both sides
//! are reported. Details in the `matching` module.
//!
//! # Baseline model (what fit-material assumes)
//!
//! For matched mode k and channel c, with ω_k = 2π f_k:
//!
//! * ln f_k = ln s + ln f_k^sim,
//! * d_k = (α + β ω_k²)/2 \[1/s\] (Rayleigh; α \[1/s\], β \[s\] ≥ 0), parameterised as α and
//!   b = β ω_ref² \[1/s\] (ω_ref = 2π × the geometric mean simulated frequency) so both are in
//!   1/s,
//! * ln a_kc = ln g_c + η_c (ln f_k − ln f_ref) + ln drive_k + ln ω_k: the acceleration
//!   response to an impulse ([`crate::audio::excitation`]: |s² F̃ / ω_d| ≈ ω for an impulse),
//!   one gain g_c per channel (the microphones' sensitivities, distances and the strike
//!   strength) and one amplitude tilt η_c per channel \[1\], a power law f^η_c on top of the
//!   acceleration law (bounded to ±`max_amplitude_tilt`, default 3: [`model::DEFAULT_TILT_BOUND`]).
//!
//! **Nuisances are not effects.** What a user cannot know and no physics in the catalogue
//! explains sits in the baseline and is profiled like the gains: the response quantity
//! (displacement, velocity, acceleration, pressure: a power of f), each microphone's frequency
//! response and a radiation-efficiency trend (a smooth tilt, η_c), and per-mode radiation
//! levels (the level floor τ_A below, ±50 % being ordinary). An amplitude effect must then show
//! its own signature beyond them: a contact duration its low-pass's knee (the curvature of ln a
//! in ln f), not a slope. Before the tilt, clean recordings tilted by f⁻² were reported as a
//! contact duration in 30 of 30 draws (test
//! `amplitude_tilts_from_f_minus_2_to_f_plus_2_are_nuisances_not_effects`; with it 0 of 30 for
//! every effect and tilt from f⁻² to f⁺², microphones ±0.5 apart, levels ±40 %), and a hard
//! mallet's contact is still found under a tilt. The held-out evaluation refits each held-out
//! channel's gain and tilt (properties of that microphone).
//!
//! **A room colours the levels.** When the room is established on its own evidence (the
//! reverberant excess in the residual envelopes, [`ReverbNoise`], accepted before any modal
//! effect is tried), the baseline also carries a curvature of the levels common to every
//! microphone, ln a_kc += κ (ln f_k − ln f_ref)² \[κ: 1\] ([`LevelColouration`];
//! listed among the baseline's terms as `reverb_noise (level_colouration)`). Why: a room's
//! absorption and its reverberant field give the recorded levels a smooth spectral shape
//! that every microphone shares, so the held-out microphones confirm it too; on a handful of
//! modes a tilt plus the half-sine's knee mimics it. Generator 2's rooms bent the levels down
//! at both ends (κ from −1.1 to −2.6 ± 0.5) and a contact duration was accepted in 3 of its 3
//! such cases on seeds 13 and 17 (held-out RMS 14–24, unchanged by it); with the colouration in
//! the baseline none was, and no verdict changed on the calibration sets' other cases. Without
//! a room the colouration stays out (`level_colouration = "room"`, the default): in every
//! baseline (`"always"`) it also absorbed the true contact durations of generator 2 and of
//! the bowl generator (macro-F1 0.890 → 0.807 on seed 101, 0.576 → 0.481 on seed 11), so a
//! microphone's own colouration remains untested. The real bowl's room gives κ = 0.7 ± 0.5
//! and the same three effects (held-out error 6.03 → 5.43, −10.0 %).
//!
//! **A room holds up the fast modes.** A mode recorded in a room reaches the microphone twice:
//! directly, decaying at its own rate d_k, and through the room, whose reverberant field it has
//! fed and which dies at the room's rate d_room = ln(10³)/T60 \[1/s\] (amplitude; 60 dB of
//! energy in T60). The recording at the mode's frequency is the sum, a pole at d_k plus one at
//! d_room (the convolution of e^(−d_k t) with the room's e^(−d_room t)). A mode slower than the
//! room keeps the late part to itself and the extraction reads d_k; a mode faster than the room
//! leaves its late part to the room's pole, so the pole the extraction returns decays at d_room
//! or between, and its level is the room's tail, lowered about by d_room/d_k. Its decay rate is
//! then capped near the room's and its level falls with frequency as d_k rises: a damping law
//! flatter than Rayleigh's and a low-pass on the levels, made by the room. So when the room is
//! established on its own evidence (the reverberant excess, [`ReverbNoise`], accepted before any
//! modal effect is tried), every mode whose observed decay rate is at least the slowest rate
//! the room's fit allows, ln(10³)/(T60 + 2σ_T60), has its decay and level rows set aside, in
//! the fit and the held-out tables alike: their poles say how the room rings, not how the
//! object does. Their frequency rows stay (the room does not move a mode's frequency). The
//! report lists them (`room_held` in the matching). The 2σ: a mode within the estimate's own
//! uncertainty of the room's rate cannot be told from it (on the synthetic rooms of the test
//! `a_room_holds_up_the_fast_modes_and_no_damping_law_or_contact_is_made_of_it`, T60 was
//! fitted 10 % short once, and the point estimate left a contact duration claimed in 1 of 6
//! draws; 0 of 6 with the 2σ, 6 of 6 without the rule).
//!
//! Calibrated on generator 2's sets (not on a blind seed): four plates in rooms (seed 149's
//! two, regenerated, and seed 5005's cases 002 and 003) and one of the spent seed 163 were
//! reported with a contact duration, a damping law or both (8 false claims), from the upper
//! modes' levels and decays (observed decays 10–130 1/s, the rooms' 4.7–18.7 1/s). With the
//! rows set aside 7 of the 8 are gone; seed 5005's case 003 keeps its damping law, made of
//! the room's poles that decay a little slower than the room (11–13 1/s at 3.4–8.2 kHz, where
//! the plate's own modes decay at 20–60 1/s): their observed rate alone cannot tell them from
//! the plate's. No other verdict of those sets (48 cases) or of the spent seeds 157 and 163
//! changed. Set 1's case 002 (a room and a glide) lost a false radiation factor. The real
//! bowl's room (T60 = 0.110 ± 0.007 s; 56 1/s) holds 3 of its modes; its three effects stay,
//! and its held-out error falls 3.69 → 3.08 (−16.5 %) rather than 4.11 → 3.67. On the point
//! estimate, a threshold at 0.7 × ln(10³)/T60 also set aside the bowl's fastest modes and
//! lost its damping law. `room_held_rows = false` turns the rule off. Since the room's T60 is
//! measured band by band ([`ReverbNoise`], "The room's T60"), the bowl's room is
//! 0.096 ± 0.007 s (62.9 1/s) and holds 2 of its poles (both at 4163 Hz); its three effects
//! stay, and its held-out error falls 3.71 → 3.08 (−17.1 %).
//!
//! **The rows the room leaves are truncated.** The rule keeps a mode's decay row because its
//! *measured* rate lies below the room's, c = ln d_room: a mode whose rate is above the room's
//! is kept only when its measurement came out low, and it then stays, low, in the table.
//! Read as ordinary rows the kept ones understate the upper modes' damping, the more so the
//! closer the law brings them to the room: a flatter law than Rayleigh's is made of the
//! selection. So in a table with a room ([`ModeTable::decay_ceiling`]) each decay row y
//! (a lone mode's ln d, a split pair's mean ln d) is read as a draw of N(μ, v) known to lie
//! below c: −2 ln L = ln 2πv + (y − μ)²/v + 2 ln Φ((c − μ)/√v) (Φ the normal distribution
//! function), and the ln d floor is profiled on the same likelihood. For Levenberg–Marquardt
//! the row's residual is the signed root of its deviance above its least value,
//! sign(u* − u) √(D(u) − D(u*)) with u = (μ − y)/√v, whose square is −2 ln L up to a
//! constant of the row. Far below the ceiling the row is an ordinary one. Generator 2's spent
//! seed 307 case 018 (a plate in a room of T60 0.34 s, seven microphones, Rayleigh's law) kept
//! 6 of its 55 modes' decay rows below the room's 11.9 1/s; the two highest, at 3404 and
//! 3986 Hz, where Rayleigh's law gives 14.7 and 17.9 1/s, were kept *because* they were
//! measured below 11.9, and a power law with p = 0.38 was named at ΔBIC 8.3. Replayed on the
//! saved evidence of 297 spent cases (seeds 263–313, calibration sets 9101–9104): that claim
//! and the one of seed 269 case 005 (a plate in a room of T60 0.25 s, two microphones) go, and
//! no other verdict changes. The real bowl's power law stays, at ΔBIC 3.5 rather than 5.3:
//! part of its evidence was its upper modes' rates just below the room's.
//!
//! **The Poisson ratio is a nuisance.** The simulation's ν is itself an estimate, and its
//! error moves each mode by its own sensitivity S_k = ∂ln f_k/∂ν (bending modes little,
//! breathing and torsional ones more): a pattern over the modes that a freely placed mass or a
//! support's stiffening can imitate on a handful of modes. When the simulated modes carry S_k
//! (the `diagnose` job computes them from the shapes), the baseline profiles Δν,
//! ln f_k += S_k Δν ([`PoissonShift`], bounded to ±[`MAX_POISSON_SHIFT`]; E/ρ is the scale s).
//! Off with `poisson_nuisance = false`.
//!
//! **A damping law at the measured frequency.** A mode's damping is a function of the
//! frequency it has, and that is measured to 10⁻⁵–10⁻⁴; the model's frequency carries the
//! frequency floor (the mesh's and the material's error, 0.1–2 %). Rayleigh's rate rises as
//! ω² above its knee, so a law evaluated at the model's frequency turns a frequency misfit e
//! into about 2e in ln d: a misfit already counted in the ln f row comes back in the decay
//! row, where a smooth law cannot follow it and a flexible damping curve takes part of it.
//! Every damping law (Rayleigh's and the terms' [`Term::damping`]) is therefore evaluated at
//! the mode's measured undamped frequency. Generator 2's spent seed 277 case 008 (a tube
//! with split pairs, one fit microphone, ln f floor 1.7 %; Rayleigh's decays) was named a
//! 3-knot damping law at ΔBIC 8.5 (held-out gain 2.4), its decay floor 0.011 under Rayleigh
//! going to 0: at the measured frequencies the curve lowers Σz² by 0.9 and is not offered.
//! Replayed on the saved evidence of 139 cases (generator 2's spent seeds 263–281 and
//! calibration sets 9101 and 9102, the real bowl), no other verdict changed; every accepted
//! damping law and support kept its ΔBIC within 1, and the carried masses lost 2–53 of
//! theirs (lowest now 26.9), the same double count: a mass that moves a mode's frequency
//! no longer also moves the Rayleigh rate the model gives it. The synthetic test
//! `a_frequency_misfit_does_not_come_back_in_the_decay_rows` (3 % frequency scatter on exact
//! Rayleigh decays) had a decay floor of 0.02–0.04 in 4 of 6 draws before; 0 now.
//!
//! Parameters ln s, α, b, ln g_0 … ln g_{C−1}, η_0 … η_{C−1}. Effects add terms on top (or, for the damping
//! curve, instead of Rayleigh), applied in stages: frequencies, then decay rates at the
//! measured frequencies, then amplitudes, then glides.
//!
//! # Likelihood
//!
//! Every observation is a row: ln f_k (σ = σ_f / f), ln d_k (σ_d / d, modes with d > 0),
//! ln a_kc (σ_a / a with a fixed 10 % in quadrature, below; channels with a > 0, modes with
//! drive > 0), the glide
//! y_k = (f_early − f_late)/f_k (σ = √(σ_e² + σ_l²)/f), and for a split pair its mean ln f
//! (σ = ½√(σ_l² + σ_u²)) and its split ln f_u − ln f_l (σ = √(σ_l² + σ_u²), with the split's
//! model floors [`model::SPLIT_MODEL_FLOOR`] and [`model::CARRIED_MASS_SPLIT_FLOOR`]) instead of the
//! two ln f, and likewise its mean ln d and its decay split ln d_u − ln d_l instead of the two
//! ln d. Each row is Gaussian in its (log) quantity, r_i = observed − predicted, with
//! variance σ_i² + τ_q² for q ∈ {ln f, ln d, glide, decay split}:
//!
//! −2 ln L = Σ_rows [ln 2π(σ_i² + τ_q²) + r_i² / (σ_i² + τ_q²)] + Σ_modes (amplitude block).
//!
//! The glide rows are the exception: Student-t with ν = 4 ([`model::GLIDE_T_DOF`]) and squared
//! scale v_i = σ_i² + τ_g², contributing ln v_i + (ν + 1) ln(1 + r_i²/(ν v_i)) + const (the
//! least-squares residual is its square root with r's sign, and τ_g is profiled on the same
//! likelihood). Why: the chirp fit's glide of a mode it cannot resolve (fast decay, a close
//! neighbour, a room) can be wrong by far more than its σ, and with Gaussian rows those few
//! modes set the floor whatever the model: on the blind benchmark's seed 202 case 021 the
//! well-resolved modes measured the injected uniform glide as 3.2748·10⁻³ ± 5·10⁻⁷ (truth
//! 3.2743·10⁻³), seven fast-decaying modes at 9–11 kHz as −6·10⁻³ … +6·10⁻³ ± 3·10⁻⁴, and the
//! glide gained ΔBIC 0.08. With t rows it gains 37 (g = 3.2755·10⁻³ ± 7·10⁻⁶); on the three
//! seeds no other decision changed, and the clean-data calibration below still holds.
//! One glide row per partial that the extraction cannot follow as two modes: of a split pair
//! split by less than its glide's sweep whose poles glide opposite ways, only the louder
//! pole's glide is a row ([`model::ModeEntry::glide_row`]); the weaker pole's chirp fit is
//! of what the louder one left, and the Student-t rows still let it set the floor (generator
//! 2's seed 191 case 004: ΔBIC 2.0 with it, 7.3 without).
//!
//! The decay rows of a table from which an established room has set aside its poles are the
//! other exception: each is Gaussian truncated at the room's rate, adding 2 ln Φ((c − μ)/√v)
//! (above, **The rows the room leaves are truncated**).
//!
//! The amplitudes of one mode share a level error: a drive read at a slightly wrong strike
//! point, or a radiation efficiency, scales the mode on every microphone alike. So the C
//! amplitude rows of mode k have covariance diag(σ_kc² + τ_a²) + τ_A² 11ᵀ: τ_a the floor of
//! the *mix* between microphones, τ_A that of the mode's *level*. With D_c = σ_kc² + τ_a²,
//! W = Σ_c 1/D_c and m = Σ_c (r_c/D_c)/W (Sherman–Morrison), the block contributes
//!
//! Σ_c ln 2πD_c + ln(1 + τ_A² W) + Σ_c (r_c − m)²/D_c + m²/(1/W + τ_A²),
//!
//! and the least-squares residual vector is (r_c − m)/√D_c per channel plus m/√(1/W + τ_A²).
//! With a single amplitude floor, per-mode level errors (large on real data) inflated it and
//! hid microphone-dependent patterns entirely (the rank-one radiation model then gained
//! nothing on synthetic lobes of ±60 %).
//!
//! **The least error of a level.** Every amplitude's σ_kc carries, in quadrature with what
//! the extraction measured, a fixed model error of 10 % in ln a
//! ([`model::LEVEL_MODEL_FLOOR`]), as a split carries [`model::SPLIT_MODEL_FLOOR`]. The model
//! predicts a level from the simulated mode's drive at one vertex: a strike covers a patch
//! that the vertex stands for, and the mode shape's value there is the discretisation's, so no
//! level is predicted to better than about 10 % however well the recording measured it (to
//! 0.1–1 % at 40–60 dB SNR). Without it the profiled floors could fall to zero, and then the
//! best-measured levels alone set the likelihood: generator 2's spent seed 311 case 022, a
//! uniform-shift control on a cup with two microphones and four groups of modes, whose two
//! lone modes were measured to 0.3 %, was read as a contact (side-lobe envelope, T = 0.51 ms)
//! at ΔBIC 25.6 with a held-out gain of 58.6, both amplitude floors fitted at 0, where the
//! contact's screen on the current floors had found a drop of 2.9 in Σz²: the knee, the gain
//! and the tilt threaded those two levels exactly, and each gained ln(τ²/σ²) ≈ 9. Replayed on
//! the saved evidence of 274 cases (generator 2's spent seeds 263–311, calibration sets
//! 9101–9104) and the real bowl: at 10 % that contact went and a radiation pattern beside a
//! damping law (seed 293 case 020; radiation is not among the scored effects), no other
//! verdict changed, and the bowl's report did not move (its profiled level floor is 1.1 in
//! ln a). At 5 % nothing changed. At 20 % a false contact beside a support went as well
//! (seed 307 case 009) and a true one with it (calibration set 9103 case 009, a bar on two
//! microphones whose floors had also been fitted at zero); at 30 % two more false contacts
//! (seed 271 case 006, seed 307 case 022) and one more true one (seed 283 case 023), and
//! the synthetic radiation pattern of
//! `radiation_without_positions_is_a_microphone_dependent_finding` was no longer found. 10 %
//! is what the argument above gives; no larger value was taken for its score on these sets.
//! Test: `tests/diagnose_evidence.rs` replays case 022's saved evidence (and a true contact on
//! a cup with four groups of modes, seed 283 case 006, which must stay).
//!
//! **What a level's spread is known to be.** A mode's level is ordinarily ±50 % off the
//! model's: its radiation efficiency, the microphone's place in its directivity and the strike
//! patch are nuisances no user knows, and that much is what they do. The two amplitude floors
//! are therefore profiled with a prior ([`model::level_prior`]): ν₀ = 4 pseudo-rows
//! ([`CatalogueSettings::level_prior_rows`]), each a level s₀ = ln 1.5 off its prediction
//! ([`model::ORDINARY_LEVEL_SPREAD`]), so that −2 ln L gains
//! ν₀ (ln T + (s₀² + 0.1²)/T), with T = τ² + τ_A² + 0.1² the variance of one level row,
//! least at τ² + τ_A² = s₀². The term is part of every fit's −2 ln L, so each criterion
//! compares penalised likelihoods on one footing.
//! Why: profiled from a table alone, the floors of five or six level rows fall to the model
//! floor as soon as a one-parameter level shape (a contact's null) threads them beside the
//! channel's gain and tilt, and those rows then gain n ln(τ²/0.1²): generator 2's spent seed
//! 307 case 022, a uniform-shift control on a bar with two microphones, was read as a contact
//! at ΔBIC 8.9, its floor falling from 0.29 to 0. With the prior, a scatter the size radiation
//! makes is no longer evidence for a shape, while a scatter far beyond it (a contact's fall
//! past its knee, 0.7–1.5) is weighed against the ordinary spread rather than against its own
//! inflated estimate. With many rows the data decide (200 levels: the prior moves the floor by
//! under 3 %). Replayed on the saved evidence of the spent cases (seeds 263–313, the
//! calibration sets 9101–9104) and the bowl: contact duration went from 16/6/6 (TP/FP/FN) to
//! 15/3/7 on the seeds and from 5/0/7 to 8/0/4 on the contact set 9103; no other verdict
//! changed. The weight 4 was set before that replay and not varied on it. The choice of a
//! partial's poles (matching step 6) weighs the same likelihood. With the prior, a greedy
//! choice sent the real bowl's lowest partial from its beating pair (1681/1684 Hz) to
//! 1684/1687 Hz, two readings 1.7 apart in −2 ln L; the choice is now a beam search whose ends
//! are charged for the exchanges that reached them (`selection::POLE_CHOICE_BEAM`), and keeps
//! the pair with or without the prior.
//! Tests: `tests/diagnose_evidence.rs` (seed 307 case 022; set 9103 case 000, a true contact
//! on a cup whose levels scatter by 0.72, named only with the prior) and the model's unit tests.
//!
//! The floors τ_q ≥ 0 (ln f, ln d, ln a mix, ln a level, glide, decay split) are model-error floors
//! estimated by maximum likelihood, profiled: the fit alternates Levenberg–Marquardt in the
//! parameters at fixed floors and the maximisation over the floors at fixed parameters (1-D
//! searches; coordinate descent for the two amplitude floors); both steps lower −2 ln L. On
//! real data a finite-element model is off by ~1 % in frequency from mode to mode, far beyond
//! the extraction's σ_f / f ~ 10⁻⁵; without the floors every effect with a free parameter
//! would "explain" part of that scatter and be accepted. With them, scatter widens τ, and an
//! effect gains likelihood only by explaining a *pattern* (the log-determinant terms fall
//! when τ can shrink). Frequency splits have no profiled floor: the model error of a pair's
//! common frequency cancels in its difference, so a split beyond its measurement σ is the
//! beating signature itself.
//!
//! Decay rates split the same way, with one more floor. A damping law's misfit is common to
//! two modes 0.1 % apart (the ln d floor τ_d, carried by the pair's mean row), and each mode
//! has an error of its own, variance τ_i² = (F² + τ_s²)/2: F = 0.2 % fixed
//! ([`model::DECAY_SPLIT_MODEL_FLOOR`]) and τ_s profiled on the decay-split rows, which carry
//! 2τ_i² (the mean row τ_i²/2, a lone mode's row τ_i²). On clean synthetic recordings the
//! extraction's decay splits sit within 2.2σ of the truth, so τ_s stays near 0 and a support
//! that damps one mode of a pair more than the other stands out to the extraction's
//! precision, while the law's misfit (15 % on the blind benchmark's set 2 case 025) hid it
//! mode by mode. In a reverberant room the decay rates scatter far beyond σ, pairs included,
//! and τ_s grows with that scatter instead of turning it into effects. Standard deviations
//! of the parameters come from (JᵀJ)⁻¹ of the whitened residuals at the optimum (floors
//! fixed).
//!
//! **An unresolved cluster's decay.** A pole that stands for two simulated modes or more (a
//! degenerate pair the extraction did not resolve) is the sum of modes split by less than
//! the recording resolves: they beat slowly, the fitted decay rate takes up part of the beat's
//! envelope, and that part depends on the microphone, since each hears its own mix of the
//! members. Its decay rate measures the object's damping only as far as the microphones agree
//! on it. So, with held-out recordings, the ln d row of such a pole is widened to
//! σ² + Δ², Δ its ln d less the mean ln d of the held-out extraction's poles of the same
//! cluster, and those held-out rows alike (`ModeTable::widen_unreplicated_decays`), and the
//! baseline is fitted on the widened rows. Where the microphones agree nothing changes. This
//! uses the held-out poles as the split screen does ([`BeatingPair`], "Seen by every
//! microphone"): to weigh a measurement that must be the same at every microphone, never to
//! fit an effect, and every effect's held-out test sees the same rows. Why: generator 2's
//! tubes, whose lowest bending pair comes out as one pole, decaying at 7.8 1/s on the fit
//! microphone and 10.2 1/s on the held-out one (Rayleigh's 8.8; ln d floor 0.004 from the
//! other modes), were named a non-Rayleigh damping on a clean control (seed 101 case 014);
//! another, 6.7 against 8.9 1/s, hid a true power law (seed 101 case 008). Calibrated on the
//! saved evidence of the spent seeds 71–101 (168 cases, `examples/catalogue_replay`): those
//! two verdicts and a damping law claimed beside a beating pair (seed 89 case 023) changed,
//! no other; the real bowl's report is unchanged.
//!
//! *The mirror.* The unresolved pole can be the held-out one: the fit microphones resolve
//! the pair into its members and the held-out microphone hears one pole for both, which beats
//! there. That pole's ln d row is widened by Δ, its ln d less the mean ln d of the fit's poles
//! of the cluster (each one member's, so their rows stay; the fit is unchanged). Generator
//! 2's blind seed 181 case 006, a cup with d ∝ f^0.35 and three microphones: its pair at
//! 2717 Hz decayed at 8.13 and 8.00 1/s on the fit microphones and at 7.20 ± 0.03 1/s as one
//! pole on the held-out one, and its pairs at 1019 and 7513 Hz likewise (6.64 against 5.60
//! and 5.66; 9.40 against 11.57 and 11.34); the true law, at ΔBIC 21.9, raised the held-out
//! error 3.72 → 6.90 and was rejected. Replayed on the saved evidence of 215 cases (generator
//! 2's calibration seeds 5001, 5003, 5004, 5005 and 149 and its spent seeds 157–181, set 1's
//! seed 101, the real bowl): that law found, no other verdict changed.
//!
//! *The beat, before any microphone disagrees.* Two microphones can hear one pole each for a
//! cluster and agree by chance, or the held-out one can resolve what the fit's cannot; the
//! bias is there all the same. So the pole's own ln d σ carries, from the start, how far a
//! single pole fitted to the cluster's two members can sit from their common decay rate,
//! given the split the simulation gives them, the pole's decay rate and their drives' ratio,
//! over the phase between them that the microphone sets (`unresolved::decay_bias`, the
//! root mean square of ln(d'/d)); the held-out widening adds to it. Checked on ground truth:
//! over the spent generator-2 cases whose true damping is Rayleigh's (no damping law,
//! support, room, split, mass or glide; 38 such poles), the poles' ln(d_measured/d_true) had
//! root mean squares 0.033, 0.066, 0.143 and 0.295 where the model put 0.033, 0.075, 0.153
//! and 0.226 (bins of the model's value up to 0.05, 0.1, 0.2 and 0.4), against 0.049 for the
//! 167 poles of one mode each; without it those poles' z ran to 2.7–3.9 in root mean square.
//! Why: generator 2's blind seed 229 case 003, a clean tube recorded as a displacement with
//! two microphones, four poles each standing for a pair: the one at 8480 Hz (members 12.5 Hz
//! apart, drives 2.9 and 3.2, decaying at 73.5 1/s where the true Rayleigh law gives 90.5)
//! was read as a power law at ΔBIC 5.6; with its σ of 0.23 the law gains 1.9. Replayed on the saved
//! evidence of 378 cases (the calibration seeds, the spent seeds 157–229, set 1's seed 101,
//! the real bowl): besides that one, a support claimed beside a glide (seed 193 case 016) went,
//! a true damping law was found (seed 193 case 019, ΔBIC 0.4 → 4.1) and one lost (seed 211
//! case 022, 7.5 → 3.0); the true laws' ΔBIC fell by 1.7 on average, the bowl's not at all.

//! # The catalogue
//!
//! | effect | signature | detector (screen) | model | parameters |
//! |---|---|---|---|---|
//! | [`NonRayleighDamping`] | ln d residuals bend with ln f | 3 hat functions in ln f fitted to the ln d residuals, Δχ² > 1 | ln d piecewise linear in ln f through 3 knots, replacing α, β | d at 3 knots \[1/s\] (+1 net) |
//! | [`BeatingPair`] | a degenerate cluster seen as two modes split beyond σ (and 5 % of the simulated split), the two decaying alike, centred on their cluster | \|split − predicted split\| > 3σ, decay rates within 10 % (or 3σ), leave-one-out \|z\| of the pair mean ≤ 4, split wider than the pair's own measured glide, no third line of the partial within one split (a comb) | pair at centre ∓ δ/2 in ln f | δ_c per split cluster \[1\] |
//! | [`SupportContact`] | modes moving at the support decay faster (and shift); after the fit γ > 3σ | regressions of d and ln f residuals on the support weight w (the motion along the support direction) and of ln f on w (f_ref/f)², and of split pairs' decay-split residuals on w_u − w_l (weights varying by ≥ 5 % of the largest); with the latter at z > 1.5, the beating pair's split screen | Δd = γw, Δ ln f = κw or κ_s w (f_ref/f)² (a spring), or the upper member of each split pair δ_c above the lower, which stays (`raised_members`) | γ ≥ 0 \[1/s\] (, κ or κ_s ≥ 0 \[1\], or δ_c per split cluster \[1\]) |
//! | [`ContactDuration`] | high modes weaker than their drive says | grid over T of the half-sine low-pass on the per-mode level residuals | ln a += ln \|cos(ωT/2)/(1 − (ωT/π)²)\|, or past the first null its side lobes' envelope, or a sin^p pulse with its first null f₀ in the band (p free, or Hertz's 1.5) | T \[s\]; or f₀ \[Hz\] (and p) |
//! | [`ReverbNoise`] | residual energy decaying after the strike above the measured floor, in most bands | early vs late mean ln E per band, z > 2; after the fit, a significant excess in ≥ half the bands (else rejected: signature missing) | ln E = ln(N_b + ρ_b N_b e^(−13.8t/T60)) vs ln N_b | T60 \[s\], ρ_b \[1\] per band |
//! | [`Radiation`] | the mode mix changes between microphones | top singular value of the double-centred ln a residuals vs the noise edge; correlation with ln transfer | ln a += η ln T_kc, or += u_k v_c (Σv = 0; at least 3 fit channels) | η \[1\]; or u_k, v_c \[1\] (K + C − 2) |
//! | [`AddedMass`] | frequencies low where the mass sits / toward low modes / split pairs whose lower member alone drops | regression of ln f residuals on −½w or −½f_1/f; differential shift ≥ 5·10⁻⁴; the beating pair's split screen, whose drops over ≥ 3 clusters fit one site to 2 % | Δ ln f = −½ ln(1 + μw) or −½ ln(1 + μ_f f_1/f); lower member δ_c below the upper, which stays | μ ≥ 0 \[1\]; δ_c per split cluster \[1\] |
//! | [`PitchGlide`] | early part of a decay higher in pitch (most in loud modes) | regression of the per-mode glide (the chirp fit's offset at the onset g_k, else (f_e − f_l)/f) on the model's relative energy Q² (drive²) × (f/f_ref)^p over a grid of p, or its mean, \|z\| > 2 and largest \|y_k\| ≥ 10⁻⁴ | g_k = g Q² (f_k/f_ref)^p, or = g | g \[1\], p \[1\] |
//!
//! Each effect is an [`Effect`] (name, signature, detector) that proposes one or more
//! [`Term`]s (model variants with their parameters and starting values); the physics, units
//! and detector thresholds are in each effect's module docs. The detectors only screen
//! (lenient thresholds: a detector that misses makes the criterion blind); the decision is
//! the criterion's, except that an effect must show the signature its physics requires (a
//! split pair decays alike, a room is broadband, a glide is at least 10⁻⁴): the likelihood
//! alone cannot tell an effect from a misfit of the modal model that happens to fit its form,
//! and the blind benchmark's false alarms were of that kind. [`ReverbNoise`] acts on the residual envelopes, not on the modes, and
//! evaluates itself ([`Effect::evaluate_own`]; module docs of `reverb_noise`).
//!
//! # Selection
//!
//! For each candidate, baseline + accepted effects + candidate is refitted jointly (all
//! parameters) and compared with the current model by
//!
//! ΔBIC = [−2 ln L_current] − [−2 ln L_candidate] − Δp · ln n
//!
//! (n the number of rows, Δp the candidate's net parameter count; the floors are in both
//! models). When an effect has several variants the one with the larger ΔBIC is taken. An
//! effect is **accepted** only if ΔBIC > `delta_bic_threshold` **and** its held-out error falls:
//! the RMS of the standardised residuals of the held-out modes, √(Σ z² / (n_h − p_h)), using
//! the parameters fitted on `fit` only (the held-out set's per-channel gains, and the held-out
//! channels' v of the radiation factor model, are refitted on it: they are properties of
//! those microphones, p_h of them), whitened as in the likelihood with the current model's
//! floors as the yardstick for both models (but the glide floor, below). "Falls" means that the held-out Σz² drops by more
//! than `min_held_out_gain` (Σz² with the effect taken at the degrees of freedom without it,
//! [`HeldOutChange`], so that held-out nuisance parameters do not count as a gain) (default [`DEFAULT_MIN_HELD_OUT_GAIN`] = 2: a held-out likelihood
//! ratio above e), not merely that it drops. Why: under the null an effect of k parameters
//! fitted on independent data changes the held-out Σz² by about 2 z₁·z₂ − z₂² per parameter
//! (z₂ its estimation error, z₁ the held-out data's own projection, both N(0, 1)); among null
//! fits that pass ΔBIC (|z₂| ≳ 2.5 at n ≈ 100) the held-out Σz² still falls in 10 %
//! (z₁ > z₂/2), and it falls by more than 2 in 5 % (Monte Carlo, 10⁶ draws: unconditionally
//! P(gain > 0) = 35 %, P(gain > 2) = 3.5 % for k = 1, 5.5 % for k = 2). The blind benchmark
//! (seed 101, v9) accepted two false effects whose held-out error fell by 10⁻⁵ relative or
//! less, both on reverberant cases: an added mass with a Σz² gain of 0.1, which this rule
//! rejects, and a contact duration with a gain of 2.6, which it still accepts (the threshold
//! was not raised to fit this benchmark); the true effects' gains were 4.0 or more. With
//! `held_out_dispersion` (on by default) the gain is divided by the robust over-dispersion
//! ĉ = max(1, median z² / 0.4549) of the held-out rows before the effect
//! ([`HeldOutChange::with_dispersion`]), the quasi-likelihood correction for held-out data
//! that the model misfits throughout (then every z² is inflated and so is any gain). Replayed
//! on the blind benchmark's saved evidence (seed 101, `examples/catalogue_replay`) it changed
//! no decision; on generator 2's seeds 31, 37 and 41 it removed one false damping law on a
//! reverberant cup (seed 37 case 014, whose held-out rows the room inflates throughout) and
//! changed no other verdict, and it has been on by default since.
//!
//! **The glide floor of the yardstick is the smaller one.** The yardstick is the current
//! model's floors, except the glide floor: there the smaller of the current model's and the
//! candidate's. Each floor is profiled about its model's prediction, and without a glide term
//! the glide rows are predicted as 0, so the glide floor swallows the glide under test (as it
//! does for the detector; `pitch_glide` module docs). Held-out glide rows measured to
//! 10⁻⁵ were then judged on a scale of about 2·10⁻³, where the Student-t rows grow only
//! logarithmically: generator 2's seed 107 case 016, a tube whose loudest mode glides
//! 5.1·10⁻³ (held-out 5.08·10⁻³ ± 3.4·10⁻⁵), gained 1.4 on the held-out set at ΔBIC 71.5
//! and was rejected. The glide floor stands for no nuisance, unlike the amplitude floor (per
//! mode radiation), so the tighter scale is the fair one for both models; every other effect
//! leaves it where it was. Replayed on the saved evidence of the spent seeds 71–107 (212
//! cases), it found two more true glides (seed 73 case 017, seed 107 case 016) and changed no
//! other verdict. The same rule for every floor was tried and not kept: it made radiation
//! false alarms on 12 cases, since the amplitude floor *is* the per-mode radiation nuisance.
//!
//! **A level shape is judged on the smaller amplitude floors.** A term that shapes the mode
//! levels smoothly across frequency ([`Term::shapes_levels`]: a contact's low-pass) is judged
//! with the smaller of the two models' amplitude floors (the per-row one and the per-mode
//! level one) as well. The argument is the glide's: before the contact enters, the amplitude
//! floor is profiled about levels that lack its knee, so it has swallowed the shape under
//! test, and the held-out levels are judged on that inflated scale. With one fit microphone
//! the shape and the per-mode scatter share the floor outright: generator 2's calibration
//! seed 5001 case 006 (a 0.22 ms contact on a plate, two microphones, displacement) fitted
//! T = 0.22 ms at ΔBIC 10.0 while its amplitude floor fell from 0.209 to 0.083 (ln a
//! variance), and the one held-out microphone gained 0.9 on the before floor (2.4 on the
//! smaller). The radiation factor model stays on the current model's floors: the per-mode
//! scatter it claims to explain *is* that floor. Replayed on 48 calibration cases of
//! generator 2 (the mixed seed 5003; the focused seeds 5001 of contacts, 5004 of clean
//! recordings and 5005 of plates in rooms; seed 149's two plates in rooms): two more
//! contacts found (5001/006, 5003/005), no other verdict changed.
//!
//! **A decay law is judged on the smaller decay floor.** A term that reshapes the decay law
//! across frequency ([`Term::shapes_decays`]: the damping laws that Rayleigh's misses) is
//! judged with the smaller of the two models' decay floors, by the same argument: before the
//! law enters, the decay floor is profiled about Rayleigh's misfit of it, so it has swallowed
//! the shape under test, and the held-out decays are judged on that inflated scale. It bites
//! with few modes and one fit microphone, where each extraction biases a decay its own way
//! (an unresolved pair beats differently at each microphone): generator 2's seed 167 case 008,
//! a cup with d ∝ f^0.41 on two microphones, four groups of modes, fitted at ΔBIC 21.1 with
//! the decay floor at 0.110 (ln d variance) under Rayleigh, gained 1.6 on the held-out
//! microphone and was rejected; its pair at 2474 Hz decayed at 3.1 and 3.2 1/s on the fit
//! microphone and 2.96 and 2.80 on the held-out one. The synthetic catalogue in that setting
//! (every third mode, ±30 % levels and ±10 % decays per microphone) confirms 37 of 48 true
//! laws against 31 of 48 on the floor before, and names Rayleigh's law in 1 of 48 draws
//! either way (test `a_damping_law_heard_by_one_fit_microphone_is_confirmed_by_the_other`).
//! Replayed on the saved evidence of 191 cases (generator 2's calibration seeds 5001, 5003,
//! 5004, 5005 and 149 and its spent seeds 157–179; set 1's seed 101; the real bowl): two
//! more damping laws found (167/008 and 173/014, each with one fit microphone) and one named
//! falsely (5003/011, a plate in a room whose T60 the envelopes put at 0.80 s against 0.43 s,
//! so that the room holds up 38 of its 46 fit modes and the law stands on the other 8); no
//! other verdict changed, the bowl's and set 1's included.
//!
//! **The gain is taken on a robust loss.** The held-out gain compares Σ ρ_k(z) rather than Σz²,
//! with Huber's ρ_k (quadratic to |z| = k, linear beyond; k = `held_out_huber_k`, default
//! [`DEFAULT_HELD_OUT_HUBER_K`] = 3), while the reported held-out errors stay the RMS of z. Why:
//! a held-out row the model cannot fit at all (a room's pole assigned to a mode, a mismatched
//! member) has |z| of 20–100, and any refit moves it a little: a shift δ of such a row changes
//! Σz² by 2|z|δ, so an effect that does nothing for the physics "gains" 10 from one outlier
//! (generator 2, seed 13, case 010: a contact duration in a room, held-out RMS 23.742 → 23.738,
//! Σz² gain 9.5). Under ρ_k the same row moves the sum by at most 2kδ, and rows inside k count as
//! before, so a real effect's gain (it brings outliers in, or shifts many rows) is kept. On
//! rows with every |z| ≤ k the rule is the Σz² rule above. Replayed on the calibration sets'
//! saved evidence (`examples/catalogue_replay`: the bowl generator's seed 101, generator 2's
//! spent seeds 11 and 13) it removed one false split pair in a room (seed 101 case 012) and
//! changed no other verdict; dividing by the mean z² instead (a non-robust dispersion) lost
//! four true effects there and was not taken. The reported RMS must fall as well: Huber's gain
//! can be positive while the RMS rises (rows brought inside k while others grow), and an
//! accepted effect must lower the error the report shows (generator 2's seed 37, clean case
//! 020: a radiation pattern at ΔBIC 4.2 with a Huber gain of 2.7 while the held-out RMS rose
//! 2.426 → 2.437; no other accepted effect on seeds 31 and 37 or the real bowl had a rising
//! RMS). Effects evaluated on their own data
//! (reverberation) use the same rule on their own held-out frames. Without held-out data an
//! effect is rejected as `no_held_out_data` unless `require_held_out` is false. Selection is greedy forward: the accepted candidate with the
//! largest ΔBIC enters, everything is refitted, the remaining effects are tried again, until
//! none is accepted; each effect enters at most once. Then a backward pass: each accepted
//! effect is taken out of the final model, the rest refitted, and the rule is applied to
//! putting it back (its *last-in* ΔBIC, with the same region-search charge as when it entered,
//! and its held-out gain with the reduced model's floors as the yardstick); the one with the
//! smallest last-in ΔBIC among those that fail leaves (reported as `redundant_given_others`,
//! with both ΔBICs), and the rest are tested again. Why: physics that overlap in what they
//! predict enter in the order of their gain, not of their truth. A point mass splits the
//! degenerate pairs it sits near, and an asymmetry's free split per cluster fits those splits
//! too; forward selection keeps whichever entered first even when the later one explains all
//! that the first did (generator 2's blind set named an added mass beside every split pair it
//! found, 3 of 3). Stepwise selection in both directions is the textbook remedy; it adds no
//! threshold of its own. A beating pair must also keep its signature once the others are in:
//! if every split it frees is one the other accepted effects make as the joint fit has them
//! (at least half of it) or lies within 3σ of their prediction, it leaves as redundant
//! whatever its last-in ΔBIC
//! (`beating_pair` module docs, "An asymmetry already modelled"): a mass's or a support's
//! model split is only as precise as its site, and free splits always take the rest.
//!
//! *Two readings of the same splits.* A split pair is an asymmetry's (the free splits of
//! [`BeatingPair`], about the pair's centre) or a mass's at a site no candidate region knows
//! (the `lowered_members` variant of [`AddedMass`]: the lower member drops, the upper stays),
//! or a support's that stiffens the member pressing into it by a law the model lacks (the
//! `raised_members` variant of [`SupportContact`]: the upper member rises and decays faster).
//! Both take one parameter per split cluster and differ only in where the pair's centre goes,
//! so on a pair-mean row buried in the ln f floor their ΔBICs differ by noise (generator 2's
//! spent seeds: 0.0–0.4 on three tubes with a floor of 2.7–3.8·10⁻³). A term that contests
//! another effect's reading ([`Term::contests`]) therefore enters only if its ΔBIC beats that
//! effect's, in the same round and acceptable, by `delta_bic_threshold`; otherwise the other
//! enters and the contesting candidate is reported as [`Rejection::NotBetterThanRival`]. The
//! free splits are the default reading because they claim less: an asymmetry, not an object
//! nobody mentioned. Replayed on seeds 31–47 (threshold 3, dispersion): the three masses on
//! cups that were named beating pairs (seed 41 case 017, seed 43 case 020, seed 47 case 013;
//! ΔBIC 8.0–11.3 over the free splits) became added masses, and one true beating pair on a cup
//! (seed 37 case 006, its three splits of 5.5–6.5 ‰ nearly one fraction of f, so the fitted
//! scale could put every upper member on the model: 11.7 over the free splits) became a mass;
//! macro-F1 0.821 / 0.884 / 0.745 / 0.869 / 0.810 → 0.821 / 0.833 / 0.808 / 0.932 / 0.863. The
//! real bowl's verdicts did not change. The blind seed 53 read another true split pair on a
//! cup as a mass, so the mass's reading now also needs its drops to fit one site where three
//! or more clusters can test that (`added_mass.rs`, *One site*).
//!
//! *Splits are set last.* The three readings above set a pair's split outright; every other
//! frequency term (the Poisson nuisance, a mass on the candidate region, a support's
//! stiffening) moves each member by its own amount and so changes the split too. The terms that
//! set splits ([`Term::sets_splits`]) therefore act after all the others, whatever the order
//! of acceptance: a free split means the split predicted, and a mass accepted after it moves
//! only the pair's centre. Applied in the order of acceptance instead, a mass that entered after
//! the free splits changed the splits they had set, and the bounded split (≥ 0) could not take
//! the change back: generator 2's blind seed 109 case 001 (a tube carrying 3.6 %, its loaded
//! model 1.7 Hz where the recording split a pair 0.32 Hz) had the carried mass fitted at
//! μ = 0.02 (ΔBIC −8.6) behind the free splits, where μ = 0.24 fits every lone mode to 10⁻³;
//! set last, the mass enters at ΔBIC 105.5 and the free splits leave as redundant, and the
//! carried mass stands. Replayed on the 236 spent cases of seeds 71–109, no verdict changed;
//! rerun whole, the 11 other cases whose carried mass the catalogue had rejected (ten beating
//! pairs on cups, a tube's contact) kept their verdicts.
//!
//! BIC rather than AIC(c): AIC's penalty is a constant 2 per parameter, which for a
//! one-parameter nested effect means accepting whenever χ²₁ > 2, a 16 % false-alarm rate on
//! clean data whatever n; BIC's ln n (≈ 5 for the ~140 rows of 20 modes on 4 microphones)
//! gives ~2.5 % for a free-sign parameter and less for a bounded one, and it falls as data
//! grow. The threshold on top was calibrated (test `calibration_false_alarms_at_most_two_percent`):
//! 240 seeded draws of clean evidence simulated from the baseline with the stated σ's (20
//! matched modes, 3 of them degenerate pairs, 450 Hz–7 kHz, 4 fit + 3 held-out microphones,
//! early/late frequencies, residual envelopes of 6 bands × 120 frames); an effect's
//! false-alarm rate at threshold c is the fraction of draws with ΔBIC > c. Measured at c = 0:
//! pitch glide 2.1 %, contact duration 1.7 %, added mass 0.8 %, the others ≤ 0.4 %; at c = 1
//! all ≤ 2 % (the smallest integer that does it); at c = 2 at most 0.8 % (2 of 240) per
//! effect, and with the held-out condition 2 acceptances in all 240 draws. The margin over the
//! calibrated 1 is for real residuals, which are not exactly Gaussian, and for a model that is
//! never exactly the object's: the default [`DEFAULT_DELTA_BIC_THRESHOLD`] is 3. Why 3 and not
//! 2: on generator 2's seeds 31, 37 and 41 (calibration sets) every accepted effect with
//! 2 < ΔBIC < 3 was false (4 of 4: a three-knot damping beside a mass at 2.04, contact durations
//! beside a glide and a room at 2.07 and 2.43, a radiation pattern at 2.50), three of them
//! second beside a true effect, where the first effect's model error, not noise, is what the
//! second fits; the smallest true effects were at 3.24 and 3.64. Replayed on their saved
//! evidence, 3 raised macro-F1 from 0.864 / 0.884 / 0.707 to 0.884 / 0.905 / 0.745 and changed
//! nothing on the real bowl; 2 ln 7 ≈ 3.9 (prior odds for one of seven effects) cost the two
//! smallest true effects and was not taken. Judged blind on a later seed, not on these. With a
//! model-error scatter of 0.4 % in
//! frequency, 10 % in decay and 15 % in level per mode (test
//! `false_alarms_with_model_error_scatter_at_most_five_percent`, 100 draws) at most 1 % per
//! effect was accepted. At the strengths of the effect tests with that scatter, every effect
//! was detected in 20 of 20 draws (ignored test `detection_power_at_realistic_strengths`).

//! After the final model, a row whose residual exceeds `unexplained_z` (default 4) σ, with the
//! floor of its quantity re-profiled without that mode (so a single bad mode cannot hide by
//! widening τ), is listed as **unexplained**, as is every observed mode without a simulated
//! match: nothing in the catalogue accounts for them, and the report says so instead of
//! guessing.
//!
//! # Report
//!
//! [`CatalogueReport`]: the matching; the baseline and the final model (parameters with σ,
//! floors τ, −2 ln L, n, p, BIC, held-out error with the baseline floors as the yardstick);
//! each accepted effect (variant, detector finding, ΔBIC, held-out error before/after at its
//! step, its parameters with σ in the final joint fit); each rejected effect with the reason
//! (not enough data, detector found nothing, ΔBIC too small, held-out did not improve,
//! held-out cannot test it, no held-out data) and its numbers; unexplained modes; per mode
//! the z-scores of ln f, ln d, ln a per channel and glide under the baseline and the final
//! model; the noise floor per band against the pre-roll estimate.

mod added_mass;
mod beating_pair;
mod contact_duration;
mod lm;
mod matching;
mod model;
mod non_rayleigh_damping;
mod pitch_glide;
mod poisson_shift;
mod radiation;
pub mod report;
mod reverb_noise;
mod selection;
mod support_contact;
mod unresolved;

#[cfg(test)]
mod tests;

use std::sync::Arc;

use serde::{Deserialize, Serialize};

pub use added_mass::{
    AddedMass, MassLoading, SiteFit, SitePair, SplitSites, MIN_DIFFERENTIAL_SHIFT,
};
pub use beating_pair::{BeatingPair, PairSplits, SplitClusters};
pub use contact_duration::{
    half_sine_envelope, half_sine_spectrum, sine_power_duration, sine_power_spectrum,
    ContactDuration, ContactShape, HalfSineContact, SinePowerContact, FIRST_NULL_PARAM,
    SINE_POWER_NULL_DEPTH,
};
pub use matching::{faint_poles, match_modes, Matching, Unit, DEFAULT_FAINT_POLE_DB};
pub use model::{
    fit, held_out_error, huber_sum, own_members, Fit, FloorVariances, HeldOutChi2, ModeEntry,
    ModeKey, ModeResiduals, ModeTable, Model, Prediction, Quantity, Role, Row, RowKind, SplitPair,
    DEFAULT_OWN_MEMBER_SPLIT_Z, LEVEL_FLOOR, N_FLOORS,
};
pub use non_rayleigh_damping::{NonRayleighDamping, PowerLawDamping, ThreeKnotDamping};
pub use pitch_glide::{EnergyGlide, PitchGlide};
pub use poisson_shift::{PoissonShift, MAX_POISSON_SHIFT};
pub use radiation::{FactorDirectivity, Radiation, TransferDirectivity};
pub use report::*;
pub use reverb_noise::{LevelColouration, ReverbNoise};
pub use selection::{acceptance, diagnose, diagnose_with};
pub use support_contact::{SupportContact, SupportTerm};

/// A mode extracted from the recording.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObservedMode {
    /// Damped frequency, Hz, and its standard deviation.
    pub frequency_hz: f64,
    pub sigma_frequency_hz: f64,
    /// Decay rate d of the amplitude e^(−dt), 1/s, and its standard deviation (d ≤ 0: no
    /// decay row).
    pub decay_rate: f64,
    pub sigma_decay_rate: f64,
    /// Amplitude per channel (≥ 0; 0 = not seen on that channel) and its standard deviation.
    pub amplitudes: Vec<f64>,
    pub sigma_amplitudes: Vec<f64>,
    /// (frequency, σ) in Hz from an early and a late stretch of the decay extracted
    /// separately (pitch glide; the CLI uses 0–0.15 s and 0.15–0.45 s after the onset); None
    /// when not available.
    #[serde(default)]
    pub early_frequency_hz: Option<(f64, f64)>,
    #[serde(default)]
    pub late_frequency_hz: Option<(f64, f64)>,
    /// Relative glide at the onset g and its σ [1] from the chirp fit of
    /// [`crate::analysis::extract::glide`] (f(t) = f (1 + g e^(−2dt))); when present it is the
    /// mode's pitch-glide observable instead of the early/late difference.
    #[serde(default)]
    pub glide: Option<(f64, f64)>,
}

/// A simulated mode at the fitted material.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimulatedMode {
    /// Undamped frequency, Hz.
    pub frequency_hz: f64,
    /// Strike-direction mode value at the strike point (magnitude, mass-normalised).
    pub drive: f64,
    /// Fraction of the mode's energy at the candidate support region, in [0, 1].
    pub support_weight: f64,
    /// |φ|² at the candidate added-mass region over its maximum over the modes, in [0, 1].
    pub mass_weight: f64,
    /// Id of its near-degenerate cluster (a unique id if alone).
    pub cluster: usize,
    /// |acoustic transfer| per channel when the microphone positions are known: one value per
    /// fit channel, optionally followed by one per held-out channel.
    #[serde(default)]
    pub transfer: Option<Vec<f64>>,
    /// The frequency [Hz] the matching pairs this mode by, when the simulation carried a
    /// candidate loading that the baseline leaves out (the `diagnose` job's loaded line match:
    /// the modes solved with the candidate mass, `frequency_hz` their frequency with the mass
    /// taken out again, [`AddedMass`] the mass). `None`: `frequency_hz`.
    #[serde(default)]
    pub match_frequency_hz: Option<f64>,
    /// ∂ln f/∂ν \[1\] at the simulated material (E and ρ held), when the job computed it: the
    /// baseline's Poisson nuisance ([`PoissonShift`]). A cluster's modes carry its mean.
    #[serde(default)]
    pub ln_f_per_poisson: Option<f64>,
}

impl SimulatedMode {
    /// ln of the frequency matching uses ([`Self::match_frequency_hz`] or `frequency_hz`).
    pub fn match_ln_f(&self) -> f64 {
        self.match_frequency_hz.unwrap_or(self.frequency_hz).ln()
    }
}

/// Energy envelopes of the residual (recording − modal resynthesis).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResidualEnvelopes {
    /// Frame times after the strike, s (increasing).
    pub times_s: Vec<f64>,
    /// B + 1 band edges, Hz.
    pub band_edges_hz: Vec<f64>,
    /// Energy per band (outer) and frame (inner), ≥ 0, in any consistent unit; frames with 0
    /// are skipped.
    pub energy: Vec<Vec<f64>>,
    /// Noise floor per band from the pre-roll, same unit.
    pub noise_floor_estimate: Vec<f64>,
    /// How many frames one analysis window spans (frame / hop): overlapping frames share
    /// samples, so n frames carry about n / this independent values (1 for disjoint frames).
    /// Absent in older saved evidence, which used the default 1024 / 384.
    #[serde(default = "default_frames_per_window")]
    pub frames_per_window: f64,
}

/// [`ResidualEnvelopes::frames_per_window`] of the default envelope options (1024 / 384).
fn default_frames_per_window() -> f64 {
    let o = crate::diagnose::evidence::EnvelopeOptions::default();
    o.frame as f64 / o.hop as f64
}

/// Everything the catalogue looks at.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Evidence {
    pub fit: Vec<ObservedMode>,
    /// The same strike extracted separately from other microphones or another time span
    /// (its channel count may differ from the fit's).
    #[serde(default)]
    pub held_out: Option<Vec<ObservedMode>>,
    pub simulated: Vec<SimulatedMode>,
    #[serde(default)]
    pub residual_envelopes: Option<ResidualEnvelopes>,
    /// Candidate sites of a point mass and how much a unit mass at each splits each pair of
    /// the model (the `lowered_members` variant of [`AddedMass`] is offered only when the
    /// pairs' drops fit one of them, where three or more split clusters can test it); `None`:
    /// not known, and that variant is not offered.
    #[serde(default)]
    pub split_sites: Option<SplitSites>,
}

/// When the baseline carries the level colouration ([`CatalogueSettings::level_colouration`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ColourationWhen {
    /// Only when the room is established on its own evidence (the default).
    Room,
    /// In every baseline.
    Always,
    /// Never.
    Never,
}

/// Settings of [`diagnose`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CatalogueSettings {
    /// Largest |ln f_obs − ln s − ln f_sim| of a match (0.04 ≈ 4 %).
    pub match_tolerance: f64,
    /// Largest ln-frequency distance of two observed modes sharing a cluster.
    pub max_pair_split: f64,
    /// Range of the global scale search.
    pub min_scale: f64,
    pub max_scale: f64,
    /// Accept an effect only if its ΔBIC exceeds this (calibrated; module docs).
    pub delta_bic_threshold: f64,
    /// |z| above which a residual is listed as unexplained.
    pub unexplained_z: f64,
    /// Without held-out data, reject effects that pass ΔBIC (true) or accept them on ΔBIC
    /// alone (false).
    pub require_held_out: bool,
    /// Parameters charged (× ln n in ΔBIC) to the added-mass point variant when its candidate
    /// region was chosen from the same data (the `diagnose` job picks the surface region that
    /// best explains the baseline's frequency residuals: a 2-D location, so 2); 0 when the
    /// region was given in advance.
    pub mass_region_search_params: usize,
    /// The same for the support term when its region was chosen from the same data (the
    /// `diagnose` job's support localisation: the downward-facing surface region whose motion
    /// best explains the baseline's decay residuals, a 2-D location, so 2); 0 when the region
    /// is the given default (the lowest band of the object).
    pub support_region_search_params: usize,
    /// Smallest fall of the held-out Σz² (twice the held-out log-likelihood gain) that counts
    /// as an improvement on held-out data (module docs, "Selection").
    pub min_held_out_gain: f64,
    /// Divide the held-out gain by the robust over-dispersion ĉ of the held-out rows before
    /// the effect (quasi-likelihood; module docs, "Selection").
    pub held_out_dispersion: bool,
    /// The held-out gain is taken on Huber's loss with this k (σ units) instead of on Σz²
    /// (module docs, "Selection"); `inf` gives the plain Σz².
    pub held_out_huber_k: f64,
    /// When the baseline carries the level colouration, a curvature of ln a in ln f common
    /// to every microphone ([`LevelColouration`]; module docs, "A room colours the levels").
    pub level_colouration: ColourationWhen,
    /// Once a room is established, set aside the decay and level rows of the modes that decay
    /// at least as fast as the room (module docs, "A room holds up the fast modes").
    pub room_held_rows: bool,
    /// Profile the Poisson ratio's error Δν in the baseline when the simulated modes carry
    /// their sensitivities ([`PoissonShift`]; module docs, "The Poisson ratio is a nuisance").
    pub poisson_nuisance: bool,
    /// A split pair whose observed split agrees with its simulated split within this many σ
    /// stands for its own simulated members (drive, weights, transfer each from its own
    /// member, [`own_members`]); 0 pools every split pair over its cluster.
    pub own_member_split_z: f64,
    /// An observed mode more than this many dB below another within `max_pair_split` is a
    /// faint pole, never matched as a partial of its own (`matching` module docs, step 0);
    /// `inf` turns the rule off.
    pub faint_pole_db: f64,
    /// Bound on each microphone's amplitude tilt |η_c|, the power of f beyond the acceleration
    /// law that the baseline absorbs as a nuisance ([`model::DEFAULT_TILT_BOUND`]). Once a
    /// room is established the bound is at least [`model::ROOM_TILT_BOUND`] (6).
    pub max_amplitude_tilt: f64,
    /// Weight, in rows, of the amplitude floors' prior: that many levels found
    /// [`model::ORDINARY_LEVEL_SPREAD`] (±50 %) off their prediction (module docs, "What a
    /// level's spread is known to be"; [`model::LEVEL_PRIOR_ROWS`]). 0: the floors are
    /// profiled from the table alone.
    pub level_prior_rows: f64,
    /// Threads that cost one round's pole readings at once (the choice of each partial's
    /// poles, matching step 6: a baseline fit per reading, most of the catalogue's time on a
    /// recording of many modes); none: one. The answer does not depend on it. Unset, the
    /// `diagnose` job sets its ranks' count (at most the cores here): the catalogue runs on
    /// rank 0 while the other ranks sleep.
    pub threads: Option<usize>,
}

impl Default for CatalogueSettings {
    fn default() -> Self {
        CatalogueSettings {
            match_tolerance: 0.04,
            max_pair_split: 0.03,
            min_scale: 0.8,
            max_scale: 1.25,
            delta_bic_threshold: DEFAULT_DELTA_BIC_THRESHOLD,
            unexplained_z: 4.0,
            require_held_out: true,
            mass_region_search_params: 0,
            support_region_search_params: 0,
            min_held_out_gain: DEFAULT_MIN_HELD_OUT_GAIN,
            held_out_dispersion: true,
            held_out_huber_k: DEFAULT_HELD_OUT_HUBER_K,
            level_colouration: ColourationWhen::Room,
            room_held_rows: true,
            poisson_nuisance: true,
            own_member_split_z: DEFAULT_OWN_MEMBER_SPLIT_Z,
            faint_pole_db: DEFAULT_FAINT_POLE_DB,
            max_amplitude_tilt: model::DEFAULT_TILT_BOUND,
            level_prior_rows: model::LEVEL_PRIOR_ROWS,
            threads: None,
        }
    }
}

/// The calibrated threshold (module docs, "Selection").
pub const DEFAULT_DELTA_BIC_THRESHOLD: f64 = 3.0;

/// Default held-out Σz² gain an accepted effect must exceed (module docs, "Selection").
pub const DEFAULT_MIN_HELD_OUT_GAIN: f64 = 2.0;

/// Default k of the held-out gain's Huber loss: 3σ, the usual bound past which a Gaussian
/// residual is an outlier (0.27 % of rows under the error model), fixed before any benchmark
/// was run with it (module docs, "Selection").
pub const DEFAULT_HELD_OUT_HUBER_K: f64 = 3.0;

impl CatalogueSettings {
    pub fn validate(&self) -> Result<(), CatalogueError> {
        let bad = |name: &'static str, value: f64, requirement: &'static str| {
            Err(CatalogueError::InvalidSetting {
                name,
                value,
                requirement,
            })
        };
        if !(self.match_tolerance > 0.0 && self.match_tolerance < 1.0) {
            return bad(
                "match_tolerance",
                self.match_tolerance,
                "must lie in (0, 1)",
            );
        }
        if !(self.max_pair_split > 0.0 && self.max_pair_split <= self.match_tolerance) {
            return bad(
                "max_pair_split",
                self.max_pair_split,
                "must lie in (0, match_tolerance]",
            );
        }
        if !(self.min_scale > 0.0 && self.min_scale <= 1.0) {
            return bad("min_scale", self.min_scale, "must lie in (0, 1]");
        }
        if !(self.max_scale >= 1.0 && self.max_scale.is_finite()) {
            return bad("max_scale", self.max_scale, "must be finite and ≥ 1");
        }
        if !self.delta_bic_threshold.is_finite() {
            return bad(
                "delta_bic_threshold",
                self.delta_bic_threshold,
                "must be finite",
            );
        }
        if !(self.unexplained_z > 0.0) {
            return bad("unexplained_z", self.unexplained_z, "must be positive");
        }
        if !(self.own_member_split_z >= 0.0 && self.own_member_split_z.is_finite()) {
            return bad(
                "own_member_split_z",
                self.own_member_split_z,
                "must be finite and ≥ 0",
            );
        }
        if !(self.max_amplitude_tilt >= 0.0 && self.max_amplitude_tilt.is_finite()) {
            return bad(
                "max_amplitude_tilt",
                self.max_amplitude_tilt,
                "must be finite and ≥ 0",
            );
        }
        if !(self.level_prior_rows >= 0.0 && self.level_prior_rows.is_finite()) {
            return bad(
                "level_prior_rows",
                self.level_prior_rows,
                "must be finite and ≥ 0",
            );
        }
        if !(self.faint_pole_db > 0.0) {
            return bad(
                "faint_pole_db",
                self.faint_pole_db,
                "must be positive (inf: no faint poles)",
            );
        }
        if !(self.held_out_huber_k > 0.0) {
            return bad(
                "held_out_huber_k",
                self.held_out_huber_k,
                "must be positive (inf: plain Σz²)",
            );
        }
        if !(self.min_held_out_gain >= 0.0 && self.min_held_out_gain.is_finite()) {
            return bad(
                "min_held_out_gain",
                self.min_held_out_gain,
                "must be finite and ≥ 0",
            );
        }
        Ok(())
    }
}

/// Bad input to the catalogue.
#[derive(thiserror::Error, Debug, Clone, PartialEq)]
pub enum CatalogueError {
    #[error("no observed modes to fit")]
    NoObservedModes,
    #[error("no simulated modes")]
    NoSimulatedModes,
    #[error("{set} mode {index}: {field} is {value}; {requirement}")]
    InvalidObserved {
        set: &'static str,
        index: usize,
        field: &'static str,
        value: f64,
        requirement: &'static str,
    },
    #[error("{set} mode {index} has {found} {field} but mode 0 has {expected}: one value per channel for every mode")]
    ChannelMismatch {
        set: &'static str,
        index: usize,
        field: &'static str,
        found: usize,
        expected: usize,
    },
    #[error("simulated mode {index}: {field} is {value}; {requirement}")]
    InvalidSimulated {
        index: usize,
        field: &'static str,
        value: f64,
        requirement: &'static str,
    },
    #[error("simulated mode {index} has {found} transfer values; expected {fit} (fit channels) or {total} (fit and held-out channels)")]
    TransferLength {
        index: usize,
        found: usize,
        fit: usize,
        total: usize,
    },
    #[error("residual envelopes: {0}")]
    InvalidEnvelopes(String),
    #[error("split sites: {0}")]
    InvalidSplitSites(String),
    #[error("only {matched} observed modes ({rows} observations) matched a simulated mode within ln-frequency tolerance {tolerance} after the best scale {scale:.4}; at least {needed} modes and more observations than baseline parameters are needed")]
    TooFewMatches {
        matched: usize,
        needed: usize,
        rows: usize,
        scale: f64,
        tolerance: f64,
    },
    #[error("the baseline fit gave a non-finite likelihood")]
    BaselineFailed,
    #[error("invalid setting {name} = {value}: {requirement}")]
    InvalidSetting {
        name: &'static str,
        value: f64,
        requirement: &'static str,
    },
}

fn validate_observed(set: &'static str, modes: &[ObservedMode]) -> Result<usize, CatalogueError> {
    let channels = modes.first().map_or(0, |m| m.amplitudes.len());
    for (index, m) in modes.iter().enumerate() {
        let bad = |field: &'static str, value: f64, requirement: &'static str| {
            Err(CatalogueError::InvalidObserved {
                set,
                index,
                field,
                value,
                requirement,
            })
        };
        if !(m.frequency_hz > 0.0 && m.frequency_hz.is_finite()) {
            return bad(
                "frequency_hz",
                m.frequency_hz,
                "must be positive and finite",
            );
        }
        if !(m.sigma_frequency_hz > 0.0 && m.sigma_frequency_hz.is_finite()) {
            return bad(
                "sigma_frequency_hz",
                m.sigma_frequency_hz,
                "must be positive and finite",
            );
        }
        if !m.decay_rate.is_finite() {
            return bad("decay_rate", m.decay_rate, "must be finite");
        }
        if m.decay_rate > 0.0 && !(m.sigma_decay_rate > 0.0 && m.sigma_decay_rate.is_finite()) {
            return bad(
                "sigma_decay_rate",
                m.sigma_decay_rate,
                "must be positive and finite for a decaying mode",
            );
        }
        for (field, len) in [
            ("amplitudes", m.amplitudes.len()),
            ("sigma_amplitudes", m.sigma_amplitudes.len()),
        ] {
            if len != channels {
                return Err(CatalogueError::ChannelMismatch {
                    set,
                    index,
                    field,
                    found: len,
                    expected: channels,
                });
            }
        }
        for (&a, &s) in m.amplitudes.iter().zip(&m.sigma_amplitudes) {
            if !(a >= 0.0 && a.is_finite()) {
                return bad("amplitude", a, "must be ≥ 0 and finite");
            }
            if a > 0.0 && !(s > 0.0 && s.is_finite()) {
                return bad(
                    "sigma_amplitude",
                    s,
                    "must be positive and finite where the amplitude is positive",
                );
            }
        }
        for (field, v) in [
            ("early_frequency_hz", m.early_frequency_hz),
            ("late_frequency_hz", m.late_frequency_hz),
        ] {
            if let Some((f, s)) = v {
                if !(f > 0.0 && f.is_finite()) {
                    return bad(field, f, "must be positive and finite");
                }
                if !(s > 0.0 && s.is_finite()) {
                    return bad(field, s, "needs a positive finite σ");
                }
            }
        }
    }
    Ok(channels)
}

impl Evidence {
    /// Checks every input (the fit never panics on bad input; it returns these errors).
    pub fn validate(&self) -> Result<(), CatalogueError> {
        if self.fit.is_empty() {
            return Err(CatalogueError::NoObservedModes);
        }
        if self.simulated.is_empty() {
            return Err(CatalogueError::NoSimulatedModes);
        }
        let fit_channels = validate_observed("fit", &self.fit)?;
        let held_channels = match &self.held_out {
            Some(h) => validate_observed("held-out", h)?,
            None => 0,
        };
        for (index, m) in self.simulated.iter().enumerate() {
            let bad = |field: &'static str, value: f64, requirement: &'static str| {
                Err(CatalogueError::InvalidSimulated {
                    index,
                    field,
                    value,
                    requirement,
                })
            };
            if !(m.frequency_hz > 0.0 && m.frequency_hz.is_finite()) {
                return bad(
                    "frequency_hz",
                    m.frequency_hz,
                    "must be positive and finite",
                );
            }
            if let Some(f) = m.match_frequency_hz {
                if !(f > 0.0 && f.is_finite()) {
                    return bad("match_frequency_hz", f, "must be positive and finite");
                }
            }
            if let Some(s) = m.ln_f_per_poisson {
                if !s.is_finite() {
                    return bad("ln_f_per_poisson", s, "must be finite");
                }
            }
            if !(m.drive >= 0.0 && m.drive.is_finite()) {
                return bad("drive", m.drive, "must be ≥ 0 and finite");
            }
            if !(0.0..=1.0).contains(&m.support_weight) {
                return bad("support_weight", m.support_weight, "must lie in [0, 1]");
            }
            if !(0.0..=1.0).contains(&m.mass_weight) {
                return bad("mass_weight", m.mass_weight, "must lie in [0, 1]");
            }
            if let Some(t) = &m.transfer {
                if t.len() != fit_channels && t.len() != fit_channels + held_channels {
                    return Err(CatalogueError::TransferLength {
                        index,
                        found: t.len(),
                        fit: fit_channels,
                        total: fit_channels + held_channels,
                    });
                }
                if let Some(&v) = t.iter().find(|v| !(**v >= 0.0 && v.is_finite())) {
                    return bad("transfer", v, "values must be ≥ 0 and finite");
                }
            }
        }
        if let Some(sites) = &self.split_sites {
            sites.validate()?;
        }
        if let Some(env) = &self.residual_envelopes {
            let b = env.band_edges_hz.len().saturating_sub(1);
            let fail = |msg: String| Err(CatalogueError::InvalidEnvelopes(msg));
            if b == 0 {
                return fail("need at least two band edges".into());
            }
            if env
                .band_edges_hz
                .windows(2)
                .any(|w| !(w[1] > w[0] && w[0] >= 0.0))
            {
                return fail("band edges must be non-negative and increasing".into());
            }
            if env.energy.len() != b || env.noise_floor_estimate.len() != b {
                return fail(format!(
                    "{b} bands from the edges but {} energy rows and {} noise floors",
                    env.energy.len(),
                    env.noise_floor_estimate.len()
                ));
            }
            if env.times_s.windows(2).any(|w| !(w[1] > w[0]))
                || env.times_s.iter().any(|t| !t.is_finite())
            {
                return fail("frame times must be finite and increasing".into());
            }
            for (band, row) in env.energy.iter().enumerate() {
                if row.len() != env.times_s.len() {
                    return fail(format!(
                        "band {band} has {} frames, the times {}",
                        row.len(),
                        env.times_s.len()
                    ));
                }
                if let Some(v) = row.iter().find(|v| !(**v >= 0.0 && v.is_finite())) {
                    return fail(format!(
                        "band {band} has energy {v}; energies must be ≥ 0 and finite"
                    ));
                }
            }
            if let Some(v) = env
                .noise_floor_estimate
                .iter()
                .find(|v| !(**v > 0.0 && v.is_finite()))
            {
                return fail(format!("noise floor {v}; must be positive and finite"));
            }
            if !(env.frames_per_window >= 1.0 && env.frames_per_window.is_finite()) {
                return fail(format!(
                    "frames per window {}; must be finite and at least 1",
                    env.frames_per_window
                ));
            }
        }
        Ok(())
    }
}

/// A parameter of a [`Term`]: name, unit, box bounds and typical magnitude (for the
/// finite-difference step and nothing else).
#[derive(Clone, Debug, PartialEq)]
pub struct ParamSpec {
    pub name: String,
    pub unit: &'static str,
    pub lower: f64,
    pub upper: f64,
    pub scale: f64,
}

impl ParamSpec {
    pub fn new(
        name: impl Into<String>,
        unit: &'static str,
        lower: f64,
        upper: f64,
        scale: f64,
    ) -> ParamSpec {
        ParamSpec {
            name: name.into(),
            unit,
            lower,
            upper,
            scale,
        }
    }
}

/// One model variant of an effect: its parameters and how they change the prediction. Terms
/// look modes up in the table they are given (by [`ModeKey`] or cluster, never by position),
/// so a term fitted on the fit table predicts the held-out table too.
pub trait Term: std::fmt::Debug + Send + Sync {
    /// Name of the effect it belongs to.
    fn effect(&self) -> &'static str;
    fn variant(&self) -> &'static str;
    fn params(&self) -> Vec<ParamSpec>;
    /// True if the term's damping stage overwrites Rayleigh (then α, β are held).
    fn replaces_rayleigh(&self) -> bool {
        false
    }
    /// Frequency stage: adjust ln f per mode.
    fn frequency(&self, _table: &ModeTable, _p: &[f64], _ln_f: &mut [f64]) {}
    /// True if the frequency stage sets split pairs' splits outright (free splits, or one
    /// member placed relative to the other): such terms act after every other term's frequency
    /// stage, so the split they set is the split predicted (module docs, "Selection", *Splits
    /// are set last*).
    fn sets_splits(&self) -> bool {
        false
    }
    /// Damping stage: adjust (or overwrite) the decay rate d per mode, given each mode's
    /// measured ln f (module docs, "A damping law at the measured frequency").
    fn damping(&self, _table: &ModeTable, _p: &[f64], _ln_f: &[f64], _decay: &mut [f64]) {}
    /// Amplitude stage: adjust ln a, flattened [mode · channels + channel].
    fn amplitude(&self, _table: &ModeTable, _p: &[f64], _ln_f: &[f64], _ln_a: &mut [f64]) {}
    /// Glide stage: adjust (f_early − f_late)/f per mode.
    fn glide(&self, _table: &ModeTable, _p: &[f64], _glide: &mut [f64]) {}
    /// For a held-out evaluation: a version of the term with its physical parameters `fitted`
    /// baked in and only per-channel nuisance parameters of the held-out set free, with their
    /// starting values. None (the default): everything is fixed.
    fn held_out_nuisance(
        &self,
        _fitted: &[f64],
        _held: &ModeTable,
    ) -> Option<(Arc<dyn Term>, Vec<f64>)> {
        None
    }
    /// Whether the held-out table `held` has any row this term predicts differently from the
    /// model without it. False (e.g. a free split of a pair that no held-out microphone
    /// resolves) makes the candidate [`Rejection::HeldOutCannotTest`] whatever the held-out
    /// error did: a change there comes only from the shared parameters' refit. The default,
    /// true, leaves the test to the held-out error.
    fn held_out_can_test(&self, _held: &ModeTable) -> bool {
        true
    }
    /// True for a smooth shape of the mode levels across frequency that no per-mode nuisance
    /// makes (a contact's low-pass): its held-out change is then judged with the smaller of the
    /// two models' amplitude floors (module docs, "Selection", *A level shape is judged on the
    /// smaller amplitude floors*). False (the default): the current model's, which for the
    /// radiation factor model is the very nuisance it claims to explain.
    fn shapes_levels(&self) -> bool {
        false
    }
    /// True for a smooth law of the decay rates across frequency (a damping law other than
    /// Rayleigh's): its held-out change is then judged with the smaller of the two models'
    /// decay floors (module docs, "Selection", *A decay law is judged on the smaller decay
    /// floor*). False (the default): the current model's.
    fn shapes_decays(&self) -> bool {
        false
    }
    /// After the fit: why the fitted parameters `p` ± `sigma` lack the signature the effect's
    /// physics requires (the candidate is then rejected as [`Rejection::SignatureMissing`]);
    /// None (the default): nothing more is required.
    fn signature_missing(&self, _table: &ModeTable, _p: &[f64], _sigma: &[f64]) -> Option<String> {
        None
    }
    /// The effect whose reading of the same rows this term contests, if any (module docs,
    /// "Selection", *Two readings of the same splits*): in a round where both are acceptable,
    /// this term enters only if its ΔBIC beats that effect's by `delta_bic_threshold`.
    fn contests(&self) -> Option<&'static str> {
        None
    }
}

/// A term to try, with starting values of its parameters.
#[derive(Clone, Debug)]
pub struct Proposal {
    pub term: Arc<dyn Term>,
    pub init: Vec<f64>,
}

/// What a detector saw.
#[derive(Clone, Debug)]
pub enum Detection {
    /// The data cannot carry the effect; why.
    NotEnoughData(String),
    /// The screen saw nothing; its statistic and what it means.
    Nothing { statistic: f64, detail: String },
    /// Worth a fit: the variants to try.
    Found {
        statistic: f64,
        detail: String,
        proposals: Vec<Proposal>,
    },
}

/// What adding an effect does on held-out data (module docs, "Selection").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeldOutChange {
    /// Held-out error (RMS standardised residual) without and with the effect.
    pub before: f64,
    pub after: f64,
    /// Held-out Σz² without minus with the effect, the latter at the former's degrees of
    /// freedom: d_b (e_b² − e_a²).
    pub gain: f64,
}

impl HeldOutChange {
    /// The change a held-out set that cannot test the effect records: none.
    pub fn untestable(self) -> HeldOutChange {
        HeldOutChange {
            after: self.before,
            gain: 0.0,
            ..self
        }
    }

    /// From Σz² and the degrees of freedom (rows minus the nuisance parameters fitted on the
    /// held-out rows) without (`chi2_before`, `dof_before`) and with the effect. The gain
    /// compares the two at the same degrees of freedom, so a nuisance parameter the effect fits
    /// on the held-out data (the radiation factor model's v per held-out channel) earns nothing
    /// by itself: it lowers Σz² by about its share e² while the error e is unchanged.
    pub fn new(
        chi2_before: f64,
        dof_before: f64,
        chi2_after: f64,
        dof_after: f64,
    ) -> HeldOutChange {
        HeldOutChange::with_dispersion(chi2_before, dof_before, chi2_after, dof_after, 1.0)
    }

    /// The change from `before` to `after` (`after` the same rows with the effect): the
    /// errors from Σz², the gain from the Huber sums ([`model::HeldOutChi2::huber`]), divided by
    /// `dispersion` as in [`HeldOutChange::with_dispersion`].
    pub fn with_huber(
        before: &model::HeldOutChi2,
        after: &model::HeldOutChi2,
        dispersion: f64,
    ) -> HeldOutChange {
        let errors =
            HeldOutChange::with_dispersion(before.chi2, before.dof, after.chi2, after.dof, 1.0);
        let robust = HeldOutChange::with_dispersion(
            before.huber,
            before.dof,
            after.huber,
            after.dof,
            dispersion,
        );
        HeldOutChange {
            gain: robust.gain,
            ..errors
        }
    }

    /// [`HeldOutChange::new`] with the gain divided by the over-dispersion ĉ ≥ 1 of the
    /// held-out rows before the effect ([`model::HeldOutChi2::dispersion`]; module docs,
    /// "Selection"): the quasi-likelihood form of the same test.
    pub fn with_dispersion(
        chi2_before: f64,
        dof_before: f64,
        chi2_after: f64,
        dof_after: f64,
        dispersion: f64,
    ) -> HeldOutChange {
        let (e2_before, e2_after) = (chi2_before / dof_before, chi2_after / dof_after);
        HeldOutChange {
            before: e2_before.sqrt(),
            after: e2_after.sqrt(),
            gain: dof_before * (e2_before - e2_after) / dispersion.max(1.0),
        }
    }
}

/// The outcome of an effect that evaluates itself on its own data ([`Effect::evaluate_own`]).
#[derive(Clone, Debug)]
pub enum OwnOutcome {
    NotEnoughData(String),
    Nothing {
        statistic: f64,
        detail: String,
    },
    Fitted {
        statistic: f64,
        detail: String,
        variant: &'static str,
        n_params: usize,
        delta_bic: f64,
        held_out: HeldOutChange,
        params: Vec<FittedParam>,
        /// The noise floor per band if the effect is accepted.
        floor_if_accepted: Vec<f64>,
        /// Why the fitted effect lacks its physical signature (None: it has it); such a fit is
        /// rejected whatever its ΔBIC ([`Rejection::SignatureMissing`]).
        signature_missing: Option<String>,
    },
}

#[derive(Clone, Debug)]
pub struct OwnEvaluation {
    pub outcome: OwnOutcome,
    pub noise: Option<NoiseFloorReport>,
}

/// An entry of the catalogue.
pub trait Effect: Send + Sync {
    fn name(&self) -> &'static str;
    /// How it shows in the residuals.
    fn signature(&self) -> &'static str;
    /// Screens the residuals of the current model on the fit table; proposes variants.
    fn detect(&self, table: &ModeTable, current: &Fit) -> Detection;
    /// [`Effect::detect`] with the held-out recordings' poles at hand (every pole their
    /// extraction found, matched or not), for an effect whose candidates the other microphones
    /// can contradict before anything is fitted: a split pair must ring at the same two
    /// frequencies in every recording of the strike ([`BeatingPair`]). The default ignores
    /// them.
    fn detect_with_held_out(
        &self,
        table: &ModeTable,
        _held_poles: Option<&[ObservedMode]>,
        current: &Fit,
    ) -> Detection {
        self.detect(table, current)
    }
    /// The backward pass's test beside the last-in ΔBIC (module docs, "Selection"):
    /// whether an accepted effect's signature is gone once the other accepted effects are in,
    /// as the joint fit has them (`others`: the joint fit with this effect's term taken out,
    /// nothing refitted). Some(why) to drop it; the default keeps it (its last-in ΔBIC and
    /// held-out gain decide).
    fn signature_lost_given_others(
        &self,
        _table: &ModeTable,
        _held_poles: Option<&[ObservedMode]>,
        _others: &Fit,
    ) -> Option<String> {
        None
    }
    /// Effects on data other than the modal table evaluate themselves once, independently of
    /// the modal model (Some), instead of being detected and refitted with it (None).
    fn evaluate_own(
        &self,
        _evidence: &Evidence,
        _settings: &CatalogueSettings,
    ) -> Option<OwnEvaluation> {
        None
    }
}

/// The eight effects, in the order of the module table.
pub fn catalogue() -> Vec<Box<dyn Effect>> {
    vec![
        Box::new(NonRayleighDamping),
        Box::new(BeatingPair),
        Box::new(SupportContact),
        Box::new(ContactDuration),
        Box::new(ReverbNoise),
        Box::new(Radiation),
        Box::new(AddedMass),
        Box::new(PitchGlide),
    ]
}

/// (smallest, largest) of per-mode weights; (∞, −∞) for none.
pub(crate) fn weight_range(weights: impl Iterator<Item = f64>) -> (f64, f64) {
    weights.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), w| {
        (lo.min(w), hi.max(w))
    })
}

/// Whether per-mode region weights (≥ 0) vary between the matched modes: by at least 5 % of
/// the largest, relative because the weights are normalised over every simulated mode and the
/// modes a recording shows can all sit far below the one that moves most in the region.
pub(crate) fn weights_vary(weights: impl Iterator<Item = f64>) -> bool {
    let (lo, hi) = weight_range(weights);
    hi > 0.0 && hi - lo > 0.05 * hi
}

/// Weighted least-squares line through the origin for points (x, y, w): the slope and its
/// z = slope / σ_slope (σ from the weights alone); `None` when Σ w x² is not positive.
pub(crate) fn weighted_regression_through_origin(
    points: impl Iterator<Item = (f64, f64, f64)> + Clone,
) -> Option<(f64, f64)> {
    let sxx: f64 = points.clone().map(|p| p.2 * p.0 * p.0).sum();
    let sxy: f64 = points.map(|p| p.2 * p.0 * p.1).sum();
    (sxx > 0.0).then(|| (sxy / sxx, sxy / sxx.sqrt()))
}

/// Weighted least-squares line y = a + b x through points (x, y, w): (a, b, Σ w (x − x̄)²);
/// `None` when the weights sum to nothing or x does not vary.
pub(crate) fn weighted_line(points: &[(f64, f64, f64)]) -> Option<(f64, f64, f64)> {
    let sw: f64 = points.iter().map(|p| p.2).sum();
    if !(sw > 0.0) {
        return None;
    }
    let mx = points.iter().map(|p| p.2 * p.0).sum::<f64>() / sw;
    let my = points.iter().map(|p| p.2 * p.1).sum::<f64>() / sw;
    let sxx: f64 = points.iter().map(|p| p.2 * (p.0 - mx).powi(2)).sum();
    if !(sxx > 0.0) {
        return None;
    }
    let sxy: f64 = points.iter().map(|p| p.2 * (p.0 - mx) * (p.1 - my)).sum();
    let slope = sxy / sxx;
    Some((my - slope * mx, slope, sxx))
}

/// Slope b of y = b x through the origin for points (x, y, s²), each y with its known variance
/// s² > 0 plus one unknown floor τ² ≥ 0 common to all, and b's signed likelihood-ratio
/// statistic z = sign(b) √(2 (ℓ₁ − ℓ₀)), τ² profiled under both the null (b = 0,
/// [`lm::profile_floor`]) and the alternative (b re-solved by weighted least squares at each
/// τ², over the same range with [`lm::minimise_nonnegative`]). `None` without points, when
/// Σ x² is not positive or when some s² is not.
///
/// Why not the Wald z with the floor the null profiles: on n points that floor takes up every
/// residual the slope would explain, and z ≤ √n whatever the precision (the support's module
/// docs, *Within split pairs*). Under the alternative the floor shrinks to what the line
/// leaves.
pub(crate) fn profiled_slope_through_origin(points: &[(f64, f64, f64)]) -> Option<(f64, f64)> {
    let sxx: f64 = points.iter().map(|p| p.0 * p.0).sum();
    if points.is_empty() || !(sxx > 0.0) || !points.iter().all(|p| p.2 > 0.0) {
        return None;
    }
    let y: Vec<f64> = points.iter().map(|p| p.1).collect();
    let s2: Vec<f64> = points.iter().map(|p| p.2).collect();
    // The slope at floor τ² and −2ℓ there (up to a constant).
    let slope = |tau2: f64| {
        let sxx: f64 = points.iter().map(|p| p.0 * p.0 / (p.2 + tau2)).sum();
        let sxy: f64 = points.iter().map(|p| p.0 * p.1 / (p.2 + tau2)).sum();
        sxy / sxx
    };
    let m2l = |tau2: f64, b: f64| -> f64 {
        points
            .iter()
            .map(|p| (p.2 + tau2).ln() + (p.1 - b * p.0).powi(2) / (p.2 + tau2))
            .sum()
    };
    let null = m2l(lm::profile_floor(&y, &s2), 0.0);
    // The range `lm::profile_floor` searches.
    let s2_min = s2.iter().cloned().fold(f64::INFINITY, f64::min);
    let s2_max = s2.iter().cloned().fold(0.0, f64::max);
    let y2_max = y.iter().map(|y| y * y).fold(0.0, f64::max);
    let tau2 =
        lm::minimise_nonnegative(|t| m2l(t, slope(t)), 1e-4 * s2_min, 10.0 * y2_max + s2_max);
    let b = slope(tau2);
    Some((b, b.signum() * (null - m2l(tau2, b)).max(0.0).sqrt()))
}

/// Weighted least-squares line through points (x, y, w) with an intercept: the slope and its
/// z = slope / σ_slope (σ from the weights alone). (0, 0) when x does not vary.
pub(crate) fn weighted_regression(points: &[(f64, f64, f64)]) -> (f64, f64) {
    weighted_line(points).map_or((0.0, 0.0), |(_, slope, sxx)| (slope, slope * sxx.sqrt()))
}
