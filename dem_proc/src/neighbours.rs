//! Linked-cell neighbour search into a Verlet pair list with a skin.
//!
//! Cells are at least as wide as the largest interaction range
//! (2 r_max + skin), so every candidate partner of a grain lies in its own or
//! one of the 26 adjacent cells. Grains outside the grid are clamped into the
//! border cells; the clamp is monotone, so no pair is lost.
//!
//! The list is stored as rows: row i holds the partners j > i, sorted by j,
//! so walking the rows visits the touching pairs in a fixed order (by index)
//! whatever the candidate set: forces do not depend on when the list was
//! rebuilt (see `World::compute_contact_forces`).

/// Largest number of cells a grid may have (4 M cells, 16 MB of cell starts).
const MAX_CELLS: usize = 1 << 22;

/// Uniform grid over the domain.
#[derive(Debug, Clone)]
pub struct CellGrid {
    origin: [f64; 3],
    /// Cells per metre along each axis.
    inv_cell: [f64; 3],
    dims: [usize; 3],
    /// First grain of each cell in `sorted` (len = cells + 1).
    cell_start: Vec<u32>,
    sorted: Vec<u32>,
    cell_of: Vec<u32>,
    fill: Vec<u32>,
    /// Per part of the rows, the list being built (kept between builds).
    parts: Vec<RowPart>,
}

/// Rows `rows` of a pair list under construction, built by one task.
#[derive(Debug, Clone, Default)]
struct RowPart {
    j: Vec<u32>,
    spring: Vec<[f64; 3]>,
    row_len: Vec<u32>,
}

/// Parts the rows are cut into for a parallel build. The list is the same
/// whatever the count (each row is sorted by j), so this only sets the grain.
const BUILD_PARTS: usize = 8;

impl CellGrid {
    pub fn new(min: [f64; 3], max: [f64; 3], cell: f64) -> Self {
        // Cells may be wider than `cell` (floor), never narrower. A domain huge
        // against the grains gets wider cells rather than an unbounded grid
        // (every rebuild clears all cells).
        let mut cell = cell;
        let mut dims = [1usize; 3];
        loop {
            for a in 0..3 {
                dims[a] = (((max[a] - min[a]) / cell).floor() as usize).clamp(1, 1 << 20);
            }
            if dims.iter().product::<usize>() <= MAX_CELLS {
                break;
            }
            cell *= 1.25;
        }
        let inv_cell = [0, 1, 2].map(|a| dims[a] as f64 / (max[a] - min[a]));
        let cells = dims[0] * dims[1] * dims[2];
        Self {
            origin: min,
            inv_cell,
            dims,
            cell_start: vec![0; cells + 1],
            sorted: Vec::new(),
            cell_of: Vec::new(),
            fill: Vec::new(),
            parts: vec![RowPart::default(); BUILD_PARTS],
        }
    }

    fn coord(&self, p: &[f64; 3]) -> [usize; 3] {
        let mut c = [0usize; 3];
        for a in 0..3 {
            let f = ((p[a] - self.origin[a]) * self.inv_cell[a]).floor();
            c[a] = if f.is_nan() || f < 0.0 { 0 } else { (f as usize).min(self.dims[a] - 1) };
        }
        c
    }

    /// Orders cells with x slowest, then z, then y: the storage order of a
    /// spatial re-sort (`World::sort_in_space`).
    pub fn sort_key(&self, p: &[f64; 3]) -> u64 {
        let c = self.coord(p);
        ((c[0] * self.dims[2] + c[2]) * self.dims[1] + c[1]) as u64
    }

    fn index(&self, c: [usize; 3]) -> usize {
        (c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]
    }

    /// Counting sort of the grains into cells.
    pub fn bin(&mut self, pos: &[[f64; 3]]) {
        let n = pos.len();
        self.cell_of.resize(n, 0);
        self.sorted.resize(n, 0);
        self.cell_start.iter_mut().for_each(|c| *c = 0);
        for (i, p) in pos.iter().enumerate() {
            let cell = self.index(self.coord(p)) as u32;
            self.cell_of[i] = cell;
            self.cell_start[cell as usize + 1] += 1;
        }
        for c in 1..self.cell_start.len() {
            self.cell_start[c] += self.cell_start[c - 1];
        }
        // Fill using the end markers, walking grains backwards keeps each cell sorted by index.
        self.fill.clear();
        self.fill.extend_from_slice(&self.cell_start);
        for i in (0..n).rev() {
            let c = self.cell_of[i] as usize + 1;
            self.fill[c] -= 1;
            self.sorted[self.fill[c] as usize] = i as u32;
        }
    }

    /// Calls `f(j)` for every grain in the 27 cells around grain `i`'s cell.
    #[inline]
    pub fn for_each_near(&self, p: &[f64; 3], mut f: impl FnMut(usize)) {
        let c = self.coord(p);
        let lo = |a: usize| c[a].saturating_sub(1);
        let hi = |a: usize| (c[a] + 1).min(self.dims[a] - 1);
        for z in lo(2)..=hi(2) {
            for y in lo(1)..=hi(1) {
                let row = (z * self.dims[1] + y) * self.dims[0];
                let start = self.cell_start[row + lo(0)] as usize;
                let end = self.cell_start[row + hi(0) + 1] as usize;
                for &j in &self.sorted[start..end] {
                    f(j as usize);
                }
            }
        }
    }
}

/// Candidate pairs with their contact history and per-step results.
#[derive(Debug, Clone, Default)]
pub struct PairList {
    /// Row starts by i (len = grains + 1).
    pub row_start: Vec<u32>,
    pub i: Vec<u32>,
    pub j: Vec<u32>,
    /// Tangential spring of each pair (history), m.
    pub spring: Vec<[f64; 3]>,
    /// Whether the pair overlapped at the last evaluation.
    pub touching: Vec<bool>,
}

impl PairList {
    pub fn len(&self) -> usize {
        self.j.len()
    }

    pub fn is_empty(&self) -> bool {
        self.j.is_empty()
    }

    /// Spring of pair (i, j), if listed.
    pub fn find(&self, i: usize, j: usize) -> Option<usize> {
        let (a, b) = (self.row_start[i] as usize, self.row_start[i + 1] as usize);
        self.j[a..b].binary_search(&(j as u32)).ok().map(|k| a + k)
    }
}

/// Rebuilds `next` from positions, carrying each listed pair's spring over from `prev`.
/// Rows are built in parallel parts and then joined in row order, so the list
/// does not depend on the thread count. Buffers are reused; no allocation
/// once they have grown.
pub fn rebuild(grid: &mut CellGrid, pos: &[[f64; 3]], radius: &[f64], skin: f64, prev: &PairList, next: &mut PairList) {
    use rayon::prelude::*;
    let n = pos.len();
    grid.bin(pos);
    let mut parts = std::mem::take(&mut grid.parts);
    let grid_ref = &*grid;
    let prev_rows = prev.row_start.len();
    parts.par_iter_mut().enumerate().for_each(|(b, part)| {
        part.j.clear();
        part.spring.clear();
        part.row_len.clear();
        for i in b * n / BUILD_PARTS..(b + 1) * n / BUILD_PARTS {
            let start = part.j.len();
            let (pi, ri) = (&pos[i], radius[i]);
            grid_ref.for_each_near(pi, |j| {
                if j > i {
                    let r = ri + radius[j] + skin;
                    let d = [pos[j][0] - pi[0], pos[j][1] - pi[1], pos[j][2] - pi[2]];
                    if d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < r * r {
                        part.j.push(j as u32);
                    }
                }
            });
            part.j[start..].sort_unstable();
            for k in start..part.j.len() {
                let j = part.j[k] as usize;
                let spring = if i + 1 < prev_rows { prev.find(i, j).map(|p| prev.spring[p]) } else { None };
                part.spring.push(spring.unwrap_or([0.0; 3]));
            }
            part.row_len.push((part.j.len() - start) as u32);
        }
    });
    next.row_start.clear();
    next.i.clear();
    next.j.clear();
    next.spring.clear();
    next.row_start.push(0);
    let mut i = 0u32;
    for part in &parts {
        next.j.extend_from_slice(&part.j);
        next.spring.extend_from_slice(&part.spring);
        for &len in &part.row_len {
            next.i.extend(std::iter::repeat_n(i, len as usize));
            next.row_start.push(next.row_start[i as usize] + len);
            i += 1;
        }
    }
    grid.parts = parts;
    let m = next.j.len();
    // Every pair counts as touching until evaluated, so the first evaluation
    // clears the springs of pairs that are apart (the buffer holds stale flags).
    next.touching.clear();
    next.touching.resize(m, true);
}
