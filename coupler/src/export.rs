//! `coupler export RUN --vtk`: a recording's points as VTK files for
//! ParaView and VisIt, one time series per kind of point:
//!
//! | series | from | point data |
//! |---|---|---|
//! | `grains` | `/dem/particles`, every frame | radius, speed, coordination |
//! | `grains_state` | `/dem/state`, the state frames | velocity, angular_velocity (vectors), radius |
//! | `liquid_surface` | `/lbm/surface` | speed, fill |
//! | `mpm_solid`, `mpm_liquid` | `/mpm/solid`, `/mpm/liquid` | the clouds' fields (phase status, porosity, pressure, …) |
//!
//! Each frame is a VTK XML UnstructuredGrid (`<series>_<k>.vtu`: the points,
//! one vertex cell each, every field as a Float32 point array, inline
//! base64 binary) and each series a ParaView collection (`<series>.pvd`)
//! whose timesteps are the simulated times, s. Written by hand: the format
//! is a few lines of XML, and the VTK crates on crates.io (vtkio) have not
//! seen a release since 2021.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use foxglove::schemas::PointCloud;
use foxglove::Decode;
use schemas::topics;

/// Where the files went and how many frames each series has.
#[derive(Debug, Default)]
pub struct Exported {
    pub series: Vec<(String, usize)>,
}

/// One frame of points: positions and named point arrays (each `components` wide).
pub(crate) struct Frame {
    /// Simulated time, s.
    pub time: f64,
    pub points: Vec<[f32; 3]>,
    /// Name, components per point, values.
    pub arrays: Vec<(String, usize, Vec<f32>)>,
}

impl Frame {
    /// A one-component point array by name.
    pub fn array(&self, name: &str) -> Option<&[f32]> {
        self.arrays.iter().find(|(n, c, _)| n == name && *c == 1).map(|(_, _, v)| v.as_slice())
    }
}

/// Writes every `every`-th frame of each series of the recording `mcap` into `out`.
pub fn export_vtk(mcap: &Path, out: &Path, every: usize) -> Result<Exported, String> {
    let bytes = std::fs::read(mcap).map_err(|e| format!("cannot read {}: {e}", mcap.display()))?;
    std::fs::create_dir_all(out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    let series: [(&str, &str); 5] = [
        (topics::DEM_PARTICLES, "grains"),
        (topics::DEM_STATE, "grains_state"),
        (topics::LBM_SURFACE, "liquid_surface"),
        (topics::MPM_SOLID, "mpm_solid"),
        (topics::MPM_LIQUID, "mpm_liquid"),
    ];
    let mut frames: Vec<Vec<Frame>> = series.iter().map(|_| Vec::new()).collect();
    let mut seen = vec![0usize; series.len()];
    let stream = mcap::MessageStream::new_with_options(&bytes, mcap::read::Options::IgnoreEndMagic.into())
        .map_err(|e| format!("{} is not an MCAP file: {e}", mcap.display()))?;
    for msg in stream {
        // A recording cut short (a killed run) exports what was read.
        let Ok(msg) = msg else { break };
        let Some(s) = series.iter().position(|(topic, _)| *topic == msg.channel.topic) else { continue };
        seen[s] += 1;
        if !(seen[s] - 1).is_multiple_of(every.max(1)) {
            continue;
        }
        let time = msg.log_time as f64 * 1e-9;
        let frame = if msg.channel.topic == topics::DEM_STATE {
            grain_state_frame(&msg.data, time)?
        } else {
            let cloud = PointCloud::decode(&msg.data[..])
                .map_err(|e| format!("a {} message does not decode: {e}", msg.channel.topic))?;
            cloud_frame(&cloud, time)?
        };
        frames[s].push(frame);
    }
    let mut exported = Exported::default();
    for ((_, name), frames) in series.iter().zip(&frames) {
        if frames.is_empty() {
            continue;
        }
        let mut pvd = String::from(
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  <Collection>\n",
        );
        for (k, frame) in frames.iter().enumerate() {
            let file = format!("{name}_{k:05}.vtu");
            write_vtu(&out.join(&file), frame)?;
            let _ = writeln!(pvd, "    <DataSet timestep=\"{:.9}\" part=\"0\" file=\"{file}\"/>", frame.time);
        }
        pvd.push_str("  </Collection>\n</VTKFile>\n");
        let path = out.join(format!("{name}.pvd"));
        std::fs::write(&path, pvd).map_err(|e| format!("cannot write {}: {e} (is the disk full?)", path.display()))?;
        exported.series.push((name.to_string(), frames.len()));
    }
    Ok(exported)
}

/// The points of a cloud: x, y, z and every other Float32 field.
pub(crate) fn cloud_frame(cloud: &PointCloud, time: f64) -> Result<Frame, String> {
    use foxglove::schemas::packed_element_field::NumericType;
    let stride = cloud.point_stride as usize;
    let n = cloud.data.len().checked_div(stride).unwrap_or(0);
    let read = |p: usize, offset: u32| {
        let at = p * stride + offset as usize;
        f32::from_le_bytes(cloud.data[at..at + 4].try_into().expect("4 bytes"))
    };
    let field = |name: &str| cloud.fields.iter().find(|f| f.name == name).map(|f| f.offset);
    let (Some(x), Some(y), Some(z)) = (field("x"), field("y"), field("z")) else {
        return Err("a point cloud without x, y, z fields".into());
    };
    let fits = |offset: u32| offset as usize + 4 <= stride;
    if ![x, y, z].into_iter().all(fits) {
        return Err("a point cloud whose fields lie beyond its stride".into());
    }
    let points = (0..n).map(|p| [read(p, x), read(p, y), read(p, z)]).collect();
    let arrays = cloud
        .fields
        .iter()
        .filter(|f| !["x", "y", "z"].contains(&f.name.as_str()))
        .filter(|f| f.r#type == NumericType::Float32 as i32 && fits(f.offset))
        .map(|f| (f.name.clone(), 1, (0..n).map(|p| read(p, f.offset)).collect()))
        .collect();
    Ok(Frame { time, points, arrays })
}

/// The grains of a `/dem/state` record, in id order.
fn grain_state_frame(bytes: &[u8], time: f64) -> Result<Frame, String> {
    let state =
        dem_proc::run::DemState::decode(bytes).map_err(|e| format!("a /dem/state record does not decode: {e}"))?;
    let g = &state.grains;
    let mut order: Vec<usize> = (0..g.pos.len()).collect();
    order.sort_by_key(|&p| state.ids.get(p).copied().unwrap_or(p as u32));
    let vec3 = |v: &[[f64; 3]]| order.iter().flat_map(|&p| v[p].map(|c| c as f32)).collect::<Vec<f32>>();
    Ok(Frame {
        time,
        points: order.iter().map(|&p| g.pos[p].map(|c| c as f32)).collect(),
        arrays: vec![
            ("velocity".into(), 3, vec3(&g.vel)),
            ("angular_velocity".into(), 3, vec3(&g.omega)),
            ("radius".into(), 1, order.iter().map(|&p| g.radius[p] as f32).collect()),
        ],
    })
}

fn write_vtu(path: &PathBuf, frame: &Frame) -> Result<(), String> {
    let n = frame.points.len();
    let mut xml = String::with_capacity(64 + n * 40);
    let _ = write!(
        xml,
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt32\">\n  <UnstructuredGrid>\n    <Piece NumberOfPoints=\"{n}\" NumberOfCells=\"{n}\">\n      <PointData>\n"
    );
    for (name, components, values) in &frame.arrays {
        data_array(&mut xml, "Float32", name, *components, values.iter().flat_map(|v| v.to_le_bytes()));
    }
    xml.push_str("      </PointData>\n      <Points>\n");
    data_array(&mut xml, "Float32", "Points", 3, frame.points.iter().flatten().flat_map(|v| v.to_le_bytes()));
    xml.push_str("      </Points>\n      <Cells>\n");
    data_array(&mut xml, "Int32", "connectivity", 1, (0..n as i32).flat_map(|i| i.to_le_bytes()));
    data_array(&mut xml, "Int32", "offsets", 1, (1..=n as i32).flat_map(|i| i.to_le_bytes()));
    // VTK_VERTEX = 1: every point is a cell of its own.
    data_array(&mut xml, "UInt8", "types", 1, std::iter::repeat_n(1u8, n));
    xml.push_str("      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n");
    std::fs::write(path, xml).map_err(|e| format!("cannot write {}: {e} (is the disk full?)", path.display()))
}

/// One inline binary DataArray: base64 of a UInt32 byte count and the bytes.
fn data_array(xml: &mut String, kind: &str, name: &str, components: usize, bytes: impl Iterator<Item = u8>) {
    let body: Vec<u8> = bytes.collect();
    let mut block = (body.len() as u32).to_le_bytes().to_vec();
    block.extend_from_slice(&body);
    let _ = writeln!(
        xml,
        "        <DataArray type=\"{kind}\" Name=\"{name}\" NumberOfComponents=\"{components}\" format=\"binary\">{}</DataArray>",
        base64(&block)
    );
}

/// Standard base64 (RFC 4648, with padding).
fn base64(bytes: &[u8]) -> String {
    const TABLE: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [chunk[0], chunk.get(1).copied().unwrap_or(0), chunk.get(2).copied().unwrap_or(0)];
        let v = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(TABLE[(v >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// RFC 4648's test vectors.
    #[test]
    fn base64_matches_the_rfc() {
        for (plain, coded) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(plain.as_bytes()), coded);
        }
    }
}
