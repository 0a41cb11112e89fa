//! A set of a grid's cells: the cells a measurement reads ([`super::Stencil::cells_read`]),
//! which a decoder can produce alone.

use super::Stencil;

/// A set of a grid's cells as a bitmap with the rank of each word (the cells before it): a
/// cell's place among the set's cells in O(1), in an eighth of the memory of their list
/// (3 MB for a 64⁴ grid, whose estimation and check sets read 2.5 M cells). Places are in
/// the order of the cells' flat indices.
#[derive(Clone, Debug)]
pub struct CellSet {
    cells: usize,
    bits: Vec<u64>,
    rank: Vec<u32>,
    count: usize,
}

impl CellSet {
    /// The cells listed, on a grid of `cells` cells.
    ///
    /// # Panics
    /// When a cell is outside the grid (a caller bug).
    pub fn new(cells: usize, listed: impl IntoIterator<Item = u32>) -> CellSet {
        let mut bits = vec![0u64; cells.div_ceil(64)];
        for f in listed {
            assert!((f as usize) < cells, "CellSet: cell {f} outside the grid");
            bits[f as usize / 64] |= 1 << (f % 64);
        }
        let mut rank = Vec::with_capacity(bits.len());
        let mut count = 0u32;
        for word in &bits {
            rank.push(count);
            count += word.count_ones();
        }
        CellSet {
            cells,
            bits,
            rank,
            count: count as usize,
        }
    }

    /// The cells `stencils` read, on a grid of `cells` cells.
    pub fn read_by<'s>(cells: usize, stencils: impl IntoIterator<Item = &'s Stencil>) -> CellSet {
        CellSet::new(cells, stencils.into_iter().flat_map(|s| s.cells_read()))
    }

    /// Cells of the grid.
    pub fn grid_cells(&self) -> usize {
        self.cells
    }

    /// Cells in the set.
    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Cell f's place among the set's cells (f in the set).
    #[inline(always)]
    pub fn position(&self, f: u32) -> u32 {
        let (w, b) = (f as usize / 64, f % 64);
        self.rank[w] + (self.bits[w] & ((1u64 << b) - 1)).count_ones()
    }

    /// The set's cells in `range` (flat indices), ascending, each with its place.
    pub fn for_each_in(&self, range: std::ops::Range<usize>, mut f: impl FnMut(u32, usize)) {
        let end = range.end.min(self.cells);
        let mut start = range.start;
        if start >= end {
            return;
        }
        let mut place = self.rank[start / 64] as usize
            + (self.bits[start / 64] & ((1u64 << (start % 64)) - 1)).count_ones() as usize;
        while start < end {
            let w = start / 64;
            let word_end = ((w + 1) * 64).min(end);
            // The word's bits from `start` to `word_end`.
            let mut word = self.bits[w] >> (start % 64);
            let width = word_end - start;
            if width < 64 {
                word &= (1u64 << width) - 1;
            }
            while word != 0 {
                f((start + word.trailing_zeros() as usize) as u32, place);
                place += 1;
                word &= word - 1;
            }
            start = word_end;
        }
    }

    /// The set's cells, ascending.
    pub fn iter(&self) -> impl Iterator<Item = u32> + '_ {
        self.bits.iter().enumerate().flat_map(|(w, &word)| {
            let mut rest = word;
            std::iter::from_fn(move || {
                (rest != 0).then(|| {
                    let b = rest.trailing_zeros();
                    rest &= rest - 1;
                    (w * 64) as u32 + b
                })
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Places, ranges and iteration against a sorted list, on sets sparse and dense and
    /// ranges starting and ending inside and across words.
    #[test]
    fn places_and_ranges_follow_the_sorted_list() {
        let mut rng = crate::math::SplitMix64::new(5);
        for (cells, density) in [(1000, 0.3), (4096, 0.02), (130, 0.9), (64, 1.0), (7, 0.0)] {
            let list: Vec<u32> = (0..cells as u32)
                .filter(|_| rng.next_f64() < density)
                .collect();
            // Listed twice and out of order: a set.
            let set = CellSet::new(cells, list.iter().rev().chain(&list).copied());
            assert_eq!(set.len(), list.len());
            assert_eq!(set.iter().collect::<Vec<_>>(), list);
            for (i, &f) in list.iter().enumerate() {
                assert_eq!(set.position(f) as usize, i);
            }
            for _ in 0..50 {
                let a = (rng.next_f64() * cells as f64) as usize;
                let b = a + (rng.next_f64() * 200.0) as usize;
                let mut got = Vec::new();
                set.for_each_in(a..b, |f, i| got.push((f, i)));
                let want: Vec<(u32, usize)> = list
                    .iter()
                    .enumerate()
                    .filter(|(_, f)| (a..b).contains(&(**f as usize)))
                    .map(|(i, &f)| (f, i))
                    .collect();
                assert_eq!(got, want, "cells {cells}, range {a}..{b}");
            }
        }
    }
}
