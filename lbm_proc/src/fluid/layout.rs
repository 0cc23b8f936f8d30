//! Where the populations of a cell live: x-segments of up to [`SEGMENT`]
//! cells.
//!
//! Each x-row of the box is cut into segments of S cells (the last one
//! padded), and a segment stores its 19 populations together, struct of
//! arrays inside it: population i of the cell at x in segment s of row r is
//! at `((r · segments + s) · Q + i) · S + x mod S`. S is [`SEGMENT`], or the
//! power of two at or above nx where rows are shorter (a 64-cell row padded
//! to 128 left half of every population run empty, and the bulk kernel
//! lost 16 %). A segment of 128 cells is 9.7 kB of f32, so the pages of
//! memory a lattice occupies are those of the segments that hold liquid
//! (or held it since the last release of dry segments,
//! `Fluid::release_dry_memory`): the array is allocated zeroed and never
//! written in the gas (`memory::sparse_zeroed`), and the operating system
//! backs only the pages touched. The page table is the block table, as in
//! SPGrid (Setaluri, Aanjaneya, Bauer & Sifakis 2014, ACM TOG 33(6) 205);
//! there is no lookup in the kernel, only this address arithmetic.
//!
//! Why x-segments and not cubes: the kernel works on x-runs of
//! [`super::LANES`] cells, and a segment of the same length keeps its pulls
//! contiguous (one cell crosses into the neighbouring segment at either
//! end). Over a whole coupled lab column (`block_census`, docs/SCALING.md)
//! the segments that ever hold liquid or its one-cell neighbourhood take
//! 240 MB (two lattices of f32 populations, a flag and an f64 mass per
//! cell), 8³ cubes 205 MB, the dense box 3119 MB.
//!
//! A stored value of 0 (f = w: rest) in a segment never written is what a
//! gas or wall cell holds anyway (`stored.rs`), so untouched memory and a
//! written gas cell are the same state.

use crate::lattice::Q;

/// Most cells per segment: the kernel's chunk length, so a chunk never spans two.
pub const SEGMENT: usize = super::LANES;

/// The address map of a box's populations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    nx: usize,
    /// Cells per segment, a power of two ≤ [`SEGMENT`], and its log2.
    segment: usize,
    shift: u32,
    segments: usize,
    rows: usize,
}

impl Layout {
    /// The layout of a box of `dims` cells (x fastest).
    pub fn new(dims: [usize; 3]) -> Self {
        let segment = dims[0].next_power_of_two().min(SEGMENT);
        Layout {
            nx: dims[0],
            segment,
            shift: segment.trailing_zeros(),
            segments: dims[0].div_ceil(segment),
            rows: dims[1] * dims[2],
        }
    }

    /// Cells per segment, and the distance between two populations of one cell.
    #[inline(always)]
    pub fn segment(&self) -> usize {
        self.segment
    }

    /// Elements the populations array holds (padding of each row's last
    /// segment included).
    pub fn len(&self) -> usize {
        self.rows * self.segments * Q * self.segment
    }

    /// Segments in the box (rows × segments per row), in memory order.
    pub fn segment_count(&self) -> usize {
        self.rows * self.segments
    }

    /// Cells of segment `k` (memory order): its row and its x-range.
    pub fn segment_cells(&self, k: usize) -> (usize, std::ops::Range<usize>) {
        let x0 = (k % self.segments) * self.segment;
        (k / self.segments, x0..(x0 + self.segment).min(self.nx))
    }

    /// Elements of segment `k`'s populations: `k · Q · S ..` one segment further.
    pub fn segment_elements(&self, k: usize) -> std::ops::Range<usize> {
        k * Q * self.segment..(k + 1) * Q * self.segment
    }

    /// Whether the box has no cells.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Population `i` of the cell at `x` in x-row `row` (`z · ny + y`).
    #[inline(always)]
    pub fn at(&self, i: usize, row: usize, x: usize) -> usize {
        // The segment is a power of two: a shift and a mask, not a division.
        (((row * self.segments + (x >> self.shift)) * Q + i) << self.shift) + (x & (self.segment - 1))
    }

    /// Population `i` of cell index `c` (x fastest).
    #[inline(always)]
    pub fn index(&self, i: usize, c: usize) -> usize {
        self.at(i, c / self.nx, c % self.nx)
    }

    /// Population 0 of cell index `c`; population i is `i ·` [`Layout::segment`] further.
    #[inline(always)]
    pub fn base(&self, c: usize) -> usize {
        self.index(0, c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_population_of_every_cell_has_its_own_slot() {
        for dims in [[1, 1, 1], [5, 3, 2], [64, 2, 2], [SEGMENT, 2, 2], [SEGMENT + 3, 2, 3], [3 * SEGMENT - 1, 1, 2]] {
            let layout = Layout::new(dims);
            let s = layout.segment();
            assert!(s.is_power_of_two() && s <= SEGMENT && (s >= dims[0] || s == SEGMENT), "{dims:?}: segment {s}");
            let n = dims[0] * dims[1] * dims[2];
            let mut seen = vec![false; layout.len()];
            for c in 0..n {
                assert_eq!(layout.base(c), layout.index(0, c));
                for i in 0..Q {
                    let k = layout.index(i, c);
                    assert_eq!(k, layout.base(c) + i * s);
                    assert!(!std::mem::replace(&mut seen[k], true), "{dims:?}: slot {k} used twice");
                }
            }
            // Only the padding of each row's last segment is left over.
            let padding = dims[1] * dims[2] * (dims[0].div_ceil(s) * s - dims[0]) * Q;
            assert_eq!(seen.iter().filter(|&&s| !s).count(), padding);
        }
    }

    /// The segments' cells and element ranges (what the release of dry
    /// memory and the rest fill walk) against the cell addressing: every
    /// cell's populations lie in the elements of the one segment that
    /// lists it, and the segments tile the array in memory order.
    #[test]
    fn segments_list_their_cells_and_own_their_elements() {
        for dims in [[5, 3, 2], [64, 2, 2], [SEGMENT + 3, 2, 3], [3 * SEGMENT - 1, 1, 2]] {
            let layout = Layout::new(dims);
            let mut owner = vec![usize::MAX; layout.len()];
            let mut next = 0;
            for k in 0..layout.segment_count() {
                let elements = layout.segment_elements(k);
                assert_eq!(elements.start, next, "{dims:?}: segment {k} does not follow the one before");
                next = elements.end;
                let (row, xs) = layout.segment_cells(k);
                assert!(!xs.is_empty() && xs.end <= dims[0]);
                for x in xs {
                    for i in 0..Q {
                        let slot = layout.at(i, row, x);
                        assert!(
                            elements.contains(&slot),
                            "{dims:?}: cell ({row}, {x}) population {i} outside segment {k}"
                        );
                        assert_eq!(std::mem::replace(&mut owner[slot], k), usize::MAX);
                    }
                }
            }
            assert_eq!(next, layout.len());
            let cells = owner.iter().filter(|&&k| k != usize::MAX).count();
            assert_eq!(cells, dims[0] * dims[1] * dims[2] * Q, "{dims:?}: every cell in exactly one segment");
        }
    }

    #[test]
    fn a_segment_holds_consecutive_cells_of_one_row() {
        let layout = Layout::new([2 * SEGMENT + 5, 3, 2]);
        let row = 4;
        for x in 1..2 * SEGMENT + 5 {
            let (a, b) = (layout.at(7, row, x - 1), layout.at(7, row, x));
            if x % SEGMENT == 0 {
                assert_eq!(b, a + (Q - 1) * SEGMENT + 1, "a new segment starts after Q populations");
            } else {
                assert_eq!(b, a + 1);
            }
        }
    }
}
