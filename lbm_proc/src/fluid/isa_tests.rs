use super::collision::*;
use super::*;

/// A collapsing block with walls, gas, an interface, Smagorinsky and a
/// body force: every branch of the row kernel.
fn collapsing_block(collision: Collision) -> Fluid<f32> {
    let params =
        FluidParams { acceleration: [0.0, 0.0, -1e-4], collision, smagorinsky: 0.16, ..FluidParams::new(0.5007) };
    let mut fluid = Fluid::<f32>::new([70, 5, 30], [Faces::Walls, Faces::Periodic, Faces::Walls], params)
        .expect("valid parameters");
    fluid.init_liquid(|[x, _, z]| x < 20 && z < 22).expect("valid block");
    // A grain's worth of forced cells, partly covered ones included, in the liquid and at its surface.
    let forced = (0..fluid.ncells()).filter_map(|c| {
        let (x, y, z) = ((c % 70) as f64, ((c / 70) % 5) as f64, (c / 350) as f64);
        let r = ((x - 10.0).powi(2) + (y - 2.0).powi(2) + (z - 20.0).powi(2)).sqrt();
        (r < 3.5).then(|| ForcedCell { cell: c, weight: (3.5 - r).min(1.0), target: [0.01, 0.0, -0.02] })
    });
    fluid.set_direct_forcing(forced).expect("valid forcing");
    fluid
}

/// A coupled run answers the DEM between the two halves of a step: the
/// forcing read-out must be final after `begin_step`, and the halves
/// together must be `step` bit for bit.
#[test]
fn a_step_in_two_halves_is_the_whole_step() {
    let mut whole = collapsing_block(Collision::Bgk);
    let mut halves = whole.clone();
    for _ in 0..40 {
        whole.step();
        halves.begin_step();
        assert_eq!(halves.applied_forcing(), whole.applied_forcing());
        halves.finish_step();
        halves.finish_step(); // nothing pending: no effect
    }
    assert!(whole.interface_cells() > 0 && whole.applied_forcing().iter().any(|a| a.force[0] != 0.0));
    assert!(halves.state() == whole.state());
    // A step begun twice finishes the first before the second.
    halves.begin_step();
    halves.begin_step();
    halves.finish_step();
    (0..2).for_each(|_| whole.step());
    assert!(halves.state() == whole.state());
}

/// A set-up change between `begin_step` and `finish_step` finishes the
/// begun step first (its conversions read the kernel's densities), so it
/// acts as it would after a whole step.
#[test]
fn a_change_between_the_halves_of_a_step_finishes_the_step_first() {
    let mut whole = collapsing_block(Collision::Bgk);
    (0..20).for_each(|_| whole.step());
    // An interface cell: its conversion reads its density.
    let c = whole.scratch.interface[whole.scratch.interface.len() / 2];
    let cell = [c % 70, (c / 70) % 5, c / 350];
    let mut halves = whole.clone();
    halves.begin_step();
    halves.set_equilibrium(cell, 1.05, [0.01, 0.0, 0.0]).expect("in the box");
    halves.step();
    whole.step();
    whole.set_equilibrium(cell, 1.05, [0.01, 0.0, 0.0]).expect("in the box");
    whole.step();
    assert!(halves.state() == whole.state());
}

/// The velocity of a forced cell includes half the force the last step
/// applied to it (Guo), looked up by row: installing the next step's list
/// (other cells, other rows) must not change what the last step applied.
#[test]
fn moments_report_the_last_applied_force_until_the_next_step() {
    let mut fluid = collapsing_block(Collision::Bgk);
    (0..5).for_each(|_| fluid.step());
    let forced = fluid.applied_forcing().iter().find(|a| a.force[0] != 0.0).expect("a forced cell").cell;
    let cell = [forced % 70, (forced / 70) % 5, forced / 350];
    let before = fluid.moments(cell).expect("in the box");
    // Reference without the force: the plain moments of the populations.
    let (_, unforced) = fluid.moments_with(forced, [0.0; 3]);
    assert!((before.1[0] - unforced[0]).abs() > 1e-9, "the applied force shows in the velocity");
    let shifted = (0..fluid.ncells()).filter(|&c| c % 70 > 40 && c / 350 < 5).map(|c| ForcedCell {
        cell: c,
        weight: 1.0,
        target: [0.0; 3],
    });
    fluid.set_direct_forcing(shifted).expect("valid forcing");
    assert_eq!(fluid.moments(cell).expect("in the box"), before);
    fluid.step();
    assert_eq!(fluid.moments_with(forced, [0.0; 3]), fluid.moments(cell).expect("in the box"), "no force now");
}

/// The conversions read each interface cell's density from the kernel's
/// sum (and their own, for cells they make interface): it must be the
/// density of the stored populations, bit for bit, after every step.
#[test]
fn kept_interface_densities_are_the_populations_densities() {
    let mut fluid = collapsing_block(Collision::Bgk);
    let mut converted = 0;
    for _ in 0..200 {
        let before = fluid.scratch.interface.clone();
        fluid.step();
        converted += fluid.scratch.interface.iter().filter(|c| before.binary_search(c).is_err()).count();
        for &c in &fluid.scratch.interface {
            assert_eq!(fluid.scratch.interface_density[c].to_bits(), fluid.density_at(c).to_bits(), "cell {c}");
        }
    }
    assert!(converted > 100, "the block's surface must move for the test to mean anything: {converted} new cells");
}

/// The recorded mass and front read the liquid plane by plane in
/// parallel, over the rows' liquid spans: the same cells, summed in the
/// same order, as a serial walk over every cell.
#[test]
fn parallel_liquid_sums_match_a_serial_walk_bit_for_bit() {
    let mut fluid = collapsing_block(Collision::Bgk);
    for step in 0..120 {
        fluid.step();
        if step % 40 != 39 {
            continue;
        }
        let serial: f64 = (0..fluid.ncells())
            .map(|c| match fluid.state.flags[c] {
                flags::FLUID => fluid.density_at(c),
                flags::INTERFACE => fluid.state.mass[c],
                _ => 0.0,
            })
            .sum::<f64>()
            + fluid.state.pending_excess;
        assert_eq!(fluid.liquid_mass().to_bits(), serial.to_bits());
        let scanned: Vec<(usize, f64)> = (0..fluid.ncells())
            .filter(|&c| fluid.fill_field()[c] > 0.0)
            .map(|c| (c, fluid.moments_at(c).0 * fluid.fill_field()[c]))
            .collect();
        assert!(scanned.len() > 1000);
        assert_eq!(fluid.liquid_cell_masses(), scanned);
    }
}

#[test]
fn lane_moments_match_one_cell_at_a_time_bit_for_bit() {
    let mut x = 0x9E37_79B9_u64;
    let mut noise = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x % 2001) as f32 * 1e-4 - 0.1
    };
    let mut f = [[0.0f32; LANES]; Q];
    f.iter_mut().flatten().for_each(|g| *g = noise());
    // Whole register blocks, a ragged last block, a full chunk, fewer lanes than a block.
    for n in [100, 103, LANES, 3] {
        let mut m = LaneMoments { drho: [0.0; LANES], j: [[0.0; LANES]; 3] };
        lane_moments(&f, n, &mut m);
        for l in 0..n {
            let (a, b) = (CellMoments::of_lane(&m, l), CellMoments::of_cell(&f, l));
            assert_eq!(a.drho.to_bits(), b.drho.to_bits(), "n {n} lane {l}");
            for d in 0..3 {
                assert_eq!(a.j[d].to_bits(), b.j[d].to_bits(), "n {n} lane {l}");
            }
        }
        assert!(m.drho[n..].iter().all(|&x| x == 0.0), "lanes from n on are left as they are");
    }
}

#[test]
fn every_instruction_set_gives_bit_identical_steps() {
    for collision in [Collision::Bgk, Collision::Trt { magic: 0.25 }] {
        let start = collapsing_block(collision);
        let mut runs = Isa::all_supported().into_iter().map(|isa| {
            let mut f = start.clone();
            f.set_isa(isa);
            assert_eq!(f.isa(), isa);
            (0..300).for_each(|_| f.step());
            (isa, f)
        });
        let (_, reference) = runs.next().expect("the baseline is always supported");
        // The block must actually have moved, and the forcing acted, for the comparison to mean anything.
        assert!(reference.interface_cells() > 0 && reference.max_speed() > 1e-3);
        assert!(reference.applied_forcing().iter().any(|a| a.force.iter().any(|&x| x != 0.0)));
        for (isa, f) in runs {
            assert!(f.state() == reference.state(), "{collision:?}: {isa:?} differs from the baseline");
        }
    }
}
