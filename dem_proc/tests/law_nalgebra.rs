//! nalgebra's `Vector3` over simba's eight-lane `AutoF64x8` runs the
//! contact law bit for bit as the solver's hand-written lanes, in every
//! regime (what `examples/law_nalgebra.rs` then times side by side; the
//! verdict is in docs/ARCHITECTURE.md, `vec3`).

use dem_proc::law::evaluate_lanes;
use dem_proc::rng::SplitMix64;

#[path = "support/contacts.rs"]
mod contacts;
#[path = "support/law_nalgebra.rs"]
mod law_nalgebra;

use law_nalgebra::{evaluate_lanes_nalgebra, lanes3, vector, ContactNa};

#[test]
fn nalgebra_lanes_round_exactly_as_the_hand_written_lanes() {
    let mut rng = SplitMix64::new(23);
    let dt = 1.4e-6;
    for law in [contacts::law(0.05, 571.4), contacts::law(0.0, 571.4), contacts::law(0.05, 0.0)] {
        for b in 0..400u64 {
            let batch = contacts::batch(&mut rng, b);
            let mut spring = batch.spring_lanes;
            let mut spring_na = vector(batch.spring_lanes);
            let out = evaluate_lanes(&law, &batch.lanes, dt, &mut spring);
            let na = evaluate_lanes_nalgebra(&law, &ContactNa::of(&batch.lanes), dt, &mut spring_na);
            let bits = |v: [dem_proc::lanes::Lanes; 3]| v.map(|l| l.0.map(f64::to_bits));
            assert_eq!(bits(lanes3(&na.force_i)), bits(out.force_i), "force, batch {b}");
            assert_eq!(bits(lanes3(&na.torque_i)), bits(out.torque_i), "torque i, batch {b}");
            assert_eq!(bits(lanes3(&na.torque_j)), bits(out.torque_j), "torque j, batch {b}");
            assert_eq!(bits(lanes3(&spring_na)), bits(spring), "spring, batch {b}");
        }
    }
}
