//! Progress inside an order, for long solves: counted in passes (one streaming of a face's slices
//! for some of its directions), logged by [`crate::solver::progress_lines`].

/// Passes in one order of a plan: every face's directions in groups of `directions_per_pass`,
/// plus one pass per sun beam swept in it (`beams`: all in order 0, those along a periodic axis
/// later, `Plan::beam_swept_in`).
pub fn passes_per_order(faces: &[usize], beams: usize, directions_per_pass: u32) -> u32 {
    let per_pass = directions_per_pass.max(1) as usize;
    let face_passes: usize = faces.iter().map(|&n| n.div_ceil(per_pass)).sum();
    (face_passes + beams) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_face_passes_and_beams() {
        assert_eq!(passes_per_order(&[25; 6], 1, 15), 6 * 2 + 1);
        assert_eq!(passes_per_order(&[25; 6], 0, 15), 12);
        assert_eq!(passes_per_order(&[25; 6], 2, 15), 14);
        assert_eq!(passes_per_order(&[1; 6], 0, 1), 6);
    }
}
