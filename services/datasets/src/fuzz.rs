//! Cheap random inputs for parser robustness tests (the parsers of rgb.txt
//! lists, trajectories and configs must return errors, never panic). Texts
//! are built from tokens that such files contain, so that random inputs get
//! past the first check often enough to reach the deeper paths.

const TOKENS: &[&str] = &[
    "1305031229.528748",
    "rgb/1.png",
    "depth/2.png",
    "0",
    "-1",
    "1e400",
    "nan",
    "inf",
    "0.5",
    " ",
    "  ",
    "\t",
    "\n",
    "#",
    ",",
    "=",
    "[",
    "]",
    "\"",
    "run",
    "mode",
    "lockstep",
    "services.slam",
    "[services.slam]",
    "keyframe_every",
    "true",
    "é",
    "\u{0}",
    "1.0 0 0 0 0 0 0 1",
    "x",
];

/// Deterministic pseudo-random texts (xorshift), `count` of them.
pub fn texts(seed: u64, count: usize) -> Vec<String> {
    let mut s = seed | 1;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    (0..count)
        .map(|_| {
            let n = (next() % 40) as usize;
            (0..n)
                .map(|_| TOKENS[(next() % TOKENS.len() as u64) as usize])
                .collect()
        })
        .collect()
}
