//! Random mutations of valid files, shared by the mutation tests.

use super::XorShift;

/// One random mutation of `src`.
pub fn mutate(rng: &mut XorShift, src: &[u8]) -> Vec<u8> {
    let mut b = src.to_vec();
    let rounds = 1 + rng.below(3);
    for _ in 0..rounds {
        if b.is_empty() {
            b.push(rng.next_u64() as u8);
            continue;
        }
        let n = b.len();
        match rng.below(8) {
            0 => {
                let i = rng.below(n);
                b[i] ^= 1 << rng.below(8);
            }
            1 => {
                let i = rng.below(n);
                b[i] = rng.next_u64() as u8;
            }
            2 => b.truncate(rng.below(n)),
            3 => {
                let i = rng.below(n);
                let len = rng.below(16).min(n - i);
                b.drain(i..i + len);
            }
            4 => {
                let i = rng.below(n + 1);
                let ins: Vec<u8> = (0..1 + rng.below(8))
                    .map(|_| rng.next_u64() as u8)
                    .collect();
                b.splice(i..i, ins);
            }
            5 => {
                // Replace a run of digits (most likely in the header) with another number.
                let digits: Vec<usize> =
                    (0..n.min(400)).filter(|&i| b[i].is_ascii_digit()).collect();
                if let Some(&i) = digits.get(rng.below(digits.len().max(1))) {
                    let j = (i..n).find(|&j| !b[j].is_ascii_digit()).unwrap_or(n);
                    let num = match rng.below(4) {
                        0 => "0".to_owned(),
                        1 => "4000000000".to_owned(),
                        2 => u64::MAX.to_string(),
                        _ => (rng.next_u64() % 1000).to_string(),
                    };
                    b.splice(i..j, num.into_bytes());
                }
            }
            6 => {
                // Duplicate a chunk.
                let i = rng.below(n);
                let len = rng.below(64).min(n - i);
                let chunk = b[i..i + len].to_vec();
                let at = rng.below(b.len() + 1);
                b.splice(at..at, chunk);
            }
            _ => {
                // Overwrite a 4-byte word (sizes, floats) with an extreme value.
                let i = rng.below(n);
                let word = match rng.below(3) {
                    0 => u32::MAX,
                    1 => 0,
                    _ => rng.next_u64() as u32,
                };
                for (k, byte) in word.to_le_bytes().iter().enumerate() {
                    if let Some(slot) = b.get_mut(i + k) {
                        *slot = *byte;
                    }
                }
            }
        }
    }
    b
}
