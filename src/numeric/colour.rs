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
    let mut colour = vec![u32::MAX; n];
    let mut n_colours = 0;
    let mut taken: Vec<u32> = Vec::new();
    for j in 0..n {
        taken.clear();
        for &i in &col_rows[j] {
            taken.extend(rows[i as usize].iter().map(|&k| colour[k as usize]));
        }
        taken.sort_unstable();
        let c = (0..).find(|c| taken.binary_search(c).is_err()).unwrap_or(0);
        colour[j] = c;
        n_colours = n_colours.max(c + 1);
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
    fn a_dense_row_forces_a_colour_per_column() {
        let rows = vec![vec![0, 1, 2, 3], vec![1]];
        let (colour, n_colours) = colour_columns(4, &rows);
        assert_eq!(n_colours, 4);
        assert_eq!(colour, [0, 1, 2, 3]);
    }
}
