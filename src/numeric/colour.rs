//! Column colouring of a sparse Jacobian (Curtis, Powell and Reid): columns
//! that share no row get one colour, so one directional derivative seeded on
//! all of them recovers each of their entries.

/// A greedy colouring of `n` columns in which no row of `rows` (each the
/// columns it holds) sees two columns of one colour: each column's colour
/// and the number of colours.
pub fn colour_columns(n: usize, rows: &[Vec<u32>]) -> (Vec<u32>, u32) {
    let mut col_rows: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (i, row) in rows.iter().enumerate() {
        for &j in row {
            col_rows[j as usize].push(i as u32);
        }
    }
    // Each row's colours so far as a bit set (`words` words a row): a
    // column takes the first colour none of its rows holds. The union of its
    // rows' sets costs a word per 64 colours a row, where gathering and
    // sorting the colours of every column of those rows cost the sum of the
    // rows' squared lengths: add20's supply rails put 2,149 of its 2,395
    // states in one row, 9.3·10^9 entries and 10.7 s.
    let mut words = 1;
    let mut used = vec![0u64; rows.len()];
    let mut colour = vec![u32::MAX; n];
    let mut n_colours = 0;
    let mut free = Vec::new();
    for j in 0..n {
        free.clear();
        free.resize(words, 0u64);
        for &i in &col_rows[j] {
            let set = &used[i as usize * words..(i as usize + 1) * words];
            for (f, &u) in free.iter_mut().zip(set) {
                *f |= u;
            }
        }
        let c = free
            .iter()
            .position(|&f| f != u64::MAX)
            .map_or(64 * words, |w| 64 * w + free[w].trailing_ones() as usize);
        if c >= 64 * words {
            // Twice the words a row, each row's set copied to its new place.
            let wider = 2 * words;
            let mut grown = vec![0u64; rows.len() * wider];
            for (i, set) in used.chunks_exact(words).enumerate() {
                grown[i * wider..i * wider + words].copy_from_slice(set);
            }
            used = grown;
            words = wider;
        }
        for &i in &col_rows[j] {
            used[i as usize * words + c / 64] |= 1 << (c % 64);
        }
        colour[j] = c as u32;
        n_colours = n_colours.max(c as u32 + 1);
    }
    (colour, n_colours)
}

/// The columns of each colour, in column order.
pub fn members(colour: &[u32], n_colours: u32) -> Vec<Vec<u32>> {
    let mut members = vec![Vec::new(); n_colours as usize];
    for (j, &c) in colour.iter().enumerate() {
        members[c as usize].push(j as u32);
    }
    members
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tridiagonal_pattern_needs_three_colours() {
        let n = 10;
        let rows: Vec<Vec<u32>> = (0..n as u32)
            .map(|i| (i.saturating_sub(1)..(i + 2).min(n as u32)).collect())
            .collect();
        let (colour, n_colours) = colour_columns(n, &rows);
        assert_eq!(n_colours, 3);
        for row in &rows {
            let mut seen: Vec<u32> = row.iter().map(|&j| colour[j as usize]).collect();
            seen.sort_unstable();
            seen.dedup();
            assert_eq!(
                seen.len(),
                row.len(),
                "a row sees one colour twice: {row:?}"
            );
        }
        assert_eq!(members(&colour, n_colours)[0], [0, 3, 6, 9]);
    }

    #[test]
    fn each_column_takes_the_first_colour_its_rows_leave_free() {
        // Random patterns, some with a dense row (a supply rail's) and more
        // than 64 colours: valid, and first fit in column order (every
        // smaller colour is held by a column before it in one of its rows).
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = |m: u64| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed % m
        };
        for _ in 0..60 {
            let n = 1 + next(200) as usize;
            let mut rows: Vec<Vec<u32>> = (0..n)
                .map(|_| {
                    let mut r: Vec<u32> = (0..next(4)).map(|_| next(n as u64) as u32).collect();
                    r.sort_unstable();
                    r.dedup();
                    r
                })
                .collect();
            if next(2) == 0 {
                rows.push((0..n as u32).filter(|_| next(4) > 0).collect());
            }
            let (colour, n_colours) = colour_columns(n, &rows);
            assert_eq!(n_colours, colour.iter().map(|&c| c + 1).max().unwrap_or(0));
            for row in &rows {
                let mut seen: Vec<u32> = row.iter().map(|&j| colour[j as usize]).collect();
                seen.sort_unstable();
                seen.dedup();
                assert_eq!(seen.len(), row.len(), "{row:?} sees a colour twice");
            }
            for j in 0..n {
                for c in 0..colour[j] {
                    let held = rows.iter().any(|row| {
                        row.contains(&(j as u32))
                            && row
                                .iter()
                                .any(|&k| (k as usize) < j && colour[k as usize] == c)
                    });
                    assert!(held, "column {j} skipped free colour {c}");
                }
            }
        }
    }

    #[test]
    fn a_dense_row_forces_a_colour_per_column() {
        let rows = vec![vec![0, 1, 2, 3], vec![1]];
        let (colour, n_colours) = colour_columns(4, &rows);
        assert_eq!(n_colours, 4);
        assert_eq!(colour, [0, 1, 2, 3]);
    }
}
