//! The DEM's half of the DEM–LBM coupling: what it sends (the grain
//! states, [`capture_states`]) and what it does with the hydrodynamic loads
//! answered ([`hold_loads`]: the world's external force and torque until
//! the next exchange). When and in what order is the run driver's
//! exchange (`runtime::coupled`, the DEM sending first; docs/coupling.md).
//!
//! Schedules (DESIGN §2):
//! - `sequential`: the load held over exchange interval n is the one the
//!   LBM computed from the grains at t_n.
//! - `concurrent`: the LBM works on exchange n while the DEM advances, so
//!   the DEM holds the load of exchange n − 1 (n = 0 waits once: there is no
//!   earlier load, and starting without buoyancy would drop every grain).
//!
//! The load is the momentum flux through each grain's surface as the LBM
//! measured it (lbm_proc `coupling`, step 6): drag, pressure, buoyancy and
//! the inertia of the liquid inside the grain, so the DEM adds nothing.

use runtime::exchange::{HydroLoad, LoadPeer, ParticleState, PeerError};

use crate::world::World;

/// Opens the DEM's side of the exchange once the grain count is known
/// (after the packing): an iceoryx2 link, or an in-process channel in tests.
pub type Connect<'a> = Box<dyn FnOnce(usize) -> Result<Box<dyn LoadPeer + 'a>, PeerError> + 'a>;

/// Holds `loads` (in id order; a grain without one holds none) as the
/// grains' external force and torque until the next exchange.
pub fn hold_loads(world: &mut World, loads: &[HydroLoad]) {
    for id in 0..world.len() {
        let (force, torque) = loads.get(id).map(|l| (l.force, l.torque)).unwrap_or_default();
        let p = world.slot(id);
        world.set_external_load(p, force, torque);
    }
}

/// Every grain's state as the exchange sends it, in id order (the peer sees
/// fixed ids whatever the storage order), into `out` (cleared first).
pub fn capture_states(world: &World, out: &mut Vec<ParticleState>) {
    let g = &world.grains;
    out.clear();
    out.extend((0..g.len()).map(|id| {
        let p = world.slot(id);
        ParticleState {
            id: id as u32,
            _pad: 0,
            position: g.pos[p],
            velocity: g.vel[p],
            angular_velocity: g.omega[p],
            radius: g.radius[p],
        }
    }));
}
