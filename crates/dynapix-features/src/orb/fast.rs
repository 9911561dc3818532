//! FAST-9 (16-pixel Bresenham circle, 9 contiguous) corner detection with 3×3 non-maximum
//! suppression on a rectangular region of interest, as OpenCV's `FAST(roi, kps, th, true)` that
//! ORB-SLAM2 calls once per 30-px cell (spec §6.2). The region is treated as a standalone image:
//! no corner within 3 px of its border, and suppression does not look outside it.

use super::imgproc::Plane;

/// Circle offsets (dx, dy) in OpenCV's order, starting at the top and going clockwise.
const CIRCLE: [(isize, isize); 16] = [
    (0, 3),
    (1, 3),
    (2, 2),
    (3, 1),
    (3, 0),
    (3, -1),
    (2, -2),
    (1, -3),
    (0, -3),
    (-1, -3),
    (-2, -2),
    (-3, -1),
    (-3, 0),
    (-3, 1),
    (-2, 2),
    (-1, 3),
];

/// Arc length of the FAST-9 test.
const ARC: usize = 9;

/// A detected corner in ROI coordinates with its FAST score.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Corner {
    pub x: usize,
    pub y: usize,
    pub score: i32,
}

/// Reusable buffers of the detector (one per worker), so cells do not allocate.
#[derive(Default)]
pub(crate) struct FastScratch {
    scores: Vec<i32>,
    cands: Vec<Corner>,
    flags: Vec<u8>,
    idx: Vec<usize>,
}

/// True when the 16-bit circular mask has ≥ 9 contiguous set bits.
#[inline(always)]
fn has_arc(m: u32) -> bool {
    let full = m | (m << 16);
    let mut acc = full;
    for s in 1..ARC as u32 {
        acc &= full >> s;
    }
    acc & 0xFFFF != 0
}

/// Linear offsets of the circle for a row stride.
fn offsets(stride: usize) -> [isize; 16] {
    let mut o = [0isize; 16];
    for (k, &(dx, dy)) in CIRCLE.iter().enumerate() {
        o[k] = dx + dy * stride as isize;
    }
    o
}

/// Corner score as OpenCV's `cornerScore<16>`: the largest threshold at which the pixel is still a
/// FAST-9 corner, minus one (never below `threshold − 1`).
#[inline]
fn corner_score(data: &[u8], c: usize, off: &[isize; 16], threshold: i32) -> i32 {
    let v = data[c] as i32;
    // Differences around the circle, wrapped so that every 9-arc is a contiguous window.
    let mut d = [0i32; 24];
    for k in 0..16 {
        d[k] = v - data[(c as isize + off[k]) as usize] as i32;
    }
    for k in 16..24 {
        d[k] = d[k - 16];
    }
    // Window minima / maxima of length 2, 4, 8 by doubling, then 9.
    let mut mn2 = [0i32; 23];
    let mut mx2 = [0i32; 23];
    for i in 0..23 {
        mn2[i] = d[i].min(d[i + 1]);
        mx2[i] = d[i].max(d[i + 1]);
    }
    let mut mn4 = [0i32; 21];
    let mut mx4 = [0i32; 21];
    for i in 0..21 {
        mn4[i] = mn2[i].min(mn2[i + 2]);
        mx4[i] = mx2[i].max(mx2[i + 2]);
    }
    let mut best = threshold;
    for i in 0..16 {
        let mn9 = mn4[i].min(mn4[i + 4]).min(d[i + 8]);
        let mx9 = mx4[i].max(mx4[i + 4]).max(d[i + 8]);
        // Centre brighter than the whole arc (mn > 0) or darker (−mx > 0).
        best = best.max(mn9).max(-mx9);
    }
    best - 1
}

/// Detects FAST-9 corners with non-maximum suppression in the ROI `(x0, y0, x1, y1)` = `[x0, x1) × [y0, y1)` of
/// `img` at `threshold`; corners are returned in row-major order, coordinates relative to
/// (x0, y0).
pub(crate) fn detect_roi(
    img: &Plane,
    roi: (usize, usize, usize, usize),
    threshold: i32,
    scratch: &mut FastScratch,
    out: &mut Vec<Corner>,
) {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        unsafe { detect_roi_avx2(avx2, img, roi, threshold, scratch, out) };
        return;
    }
    detect_roi_body(img, roi, threshold, scratch, out);
}

/// [`detect_roi_body`] compiled for AVX2: the branch-free pre-test runs 32 pixels per
/// instruction instead of 16. Integer arithmetic only, so the corners are the same.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn detect_roi_avx2(
    _: dynapix_simd::Avx2,
    img: &Plane,
    roi: (usize, usize, usize, usize),
    threshold: i32,
    scratch: &mut FastScratch,
    out: &mut Vec<Corner>,
) {
    detect_roi_body(img, roi, threshold, scratch, out);
}

#[inline(always)]
fn detect_roi_body(
    img: &Plane,
    roi: (usize, usize, usize, usize),
    threshold: i32,
    scratch: &mut FastScratch,
    out: &mut Vec<Corner>,
) {
    out.clear();
    if !scan(img, roi, threshold, scratch) {
        return;
    }
    let rw = roi.2 - roi.0;
    let sc = &scratch.scores;
    for cand in &scratch.cands {
        let (x, y, s) = (cand.x, cand.y, cand.score);
        let mut keep = true;
        'n: for ny in y - 1..=y + 1 {
            for nx in x - 1..=x + 1 {
                if (nx, ny) != (x, y) && sc[ny * rw + nx] >= s {
                    keep = false;
                    break 'n;
                }
            }
        }
        if keep {
            out.push(*cand);
        }
    }
    clear_scores(scratch, rw);
}

/// Resets the entries of `scratch.scores` that the last [`scan`] of a region `rw` wide wrote.
#[inline(always)]
fn clear_scores(scratch: &mut FastScratch, rw: usize) {
    for cand in &scratch.cands {
        scratch.scores[cand.y * rw + cand.x] = 0;
    }
}

/// The FAST-9 corners of the ROI with their scores, before suppression: into
/// `scratch.cands` (row-major, ROI coordinates) and `scratch.scores` (ROI row-major; zero
/// elsewhere, reset with [`clear_scores`]). False when the ROI is too small or outside the
/// image (no corners).
#[inline(always)]
fn scan(
    img: &Plane,
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    threshold: i32,
    scratch: &mut FastScratch,
) -> bool {
    scratch.cands.clear();
    let (rw, rh) = (x1.saturating_sub(x0), y1.saturating_sub(y0));
    if rw < 7 || rh < 7 || x1 > img.w || y1 > img.h {
        return false;
    }
    let stride = img.w;
    let off = offsets(stride);
    let data = &img.data[..];
    let t = threshold.clamp(0, 255) as u8;
    // `scores` is all zeros between calls: entries written below are reset before returning.
    if scratch.scores.len() < rw * rh {
        scratch.scores.resize(rw * rh, 0);
    }
    scratch.cands.clear();
    scratch.flags.clear();
    scratch.flags.resize(rw, 0);
    let n = rw - 6;
    for ry in 3..rh - 3 {
        let y = y0 + ry;
        // Slice k holds circle pixel k of every pixel of this row's detection span.
        let circle: [&[u8]; 16] = std::array::from_fn(|k| {
            let (dx, dy) = CIRCLE[k];
            let start = ((y as isize + dy) * stride as isize + (x0 + 3) as isize + dx) as usize;
            &data[start..start + n]
        });
        let c = &data[y * stride + x0 + 3..y * stride + x0 + 3 + n];
        // Branch-free necessary condition (vectorised): a 9-arc contains one pixel of every
        // opposite pair (k, k+8), so each pair must have a member of the arc's class.
        pretest(&c[..n], circle, t, &mut scratch.flags[..n]);
        let candidates = &mut scratch.idx;
        candidates.clear();
        for (ci, chunk) in scratch.flags[..n].chunks(8).enumerate() {
            // Most pixels fail the pre-test: skip eight at a time.
            if chunk.iter().all(|&f| f == 0) {
                continue;
            }
            for (j, &f) in chunk.iter().enumerate() {
                if f != 0 {
                    candidates.push(ci * 8 + j);
                }
            }
        }
        for &i in candidates.iter() {
            let rx = i + 3;
            let c = y * stride + x0 + rx;
            let v = data[c] as i32;
            let (hi, lo) = (v + threshold, v - threshold);
            let (mut bm, mut dm) = (0u32, 0u32);
            for (k, &o) in off.iter().enumerate() {
                let p = data[(c as isize + o) as usize] as i32;
                bm |= ((p > hi) as u32) << k;
                dm |= ((p < lo) as u32) << k;
            }
            if has_arc(bm) || has_arc(dm) {
                let s = corner_score(data, c, &off, threshold);
                scratch.scores[ry * rw + rx] = s;
                scratch.cands.push(Corner {
                    x: rx,
                    y: ry,
                    score: s,
                });
            }
        }
    }
    true
}

/// The FAST pre-test of one row: `flags[i]` = 1 when pixel i (value `c[i]`, circle pixel k
/// at `circle[k][i]`) may be a corner at threshold `t`. A function of its own, so `flags`
/// is known not to alias the inputs and the loop vectorises without run-time checks, and
/// compiled for AVX2 when the CPU has it (32 pixels per instruction; integer arithmetic,
/// the same flags).
#[inline(always)]
fn pretest(c: &[u8], circle: [&[u8]; 16], t: u8, flags: &mut [u8]) {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        unsafe { pretest_avx2(avx2, c, circle, t, flags) };
        return;
    }
    pretest_base(c, circle, t, flags);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline(never)]
fn pretest_avx2(_: dynapix_simd::Avx2, c: &[u8], circle: [&[u8]; 16], t: u8, flags: &mut [u8]) {
    pretest_body(c, circle, t, flags);
}

#[inline(never)]
fn pretest_base(c: &[u8], circle: [&[u8]; 16], t: u8, flags: &mut [u8]) {
    pretest_body(c, circle, t, flags);
}

#[inline(always)]
fn pretest_body(c: &[u8], circle: [&[u8]; 16], t: u8, flags: &mut [u8]) {
    let n = c.len().min(flags.len());
    let (c, flags) = (&c[..n], &mut flags[..n]);
    let [
        q0,
        q1,
        q2,
        q3,
        q4,
        q5,
        q6,
        q7,
        q8,
        q9,
        q10,
        q11,
        q12,
        q13,
        q14,
        q15,
    ] = circle;
    let (q0, q1, q2, q3) = (&q0[..n], &q1[..n], &q2[..n], &q3[..n]);
    let (q4, q5, q6, q7) = (&q4[..n], &q5[..n], &q6[..n], &q7[..n]);
    let (q8, q9, q10, q11) = (&q8[..n], &q9[..n], &q10[..n], &q11[..n]);
    let (q12, q13, q14, q15) = (&q12[..n], &q13[..n], &q14[..n], &q15[..n]);
    for i in 0..n {
        let v = c[i];
        let hi = v.saturating_add(t);
        let lo = v.saturating_sub(t);
        // Per pixel k: 0xFF-style masks as u8 (1 = brighter / darker than the centre ± t).
        let b = |p: u8| (p > hi) as u8;
        let d = |p: u8| (p < lo) as u8;
        let bright = (b(q0[i]) | b(q8[i]))
            & (b(q1[i]) | b(q9[i]))
            & (b(q2[i]) | b(q10[i]))
            & (b(q3[i]) | b(q11[i]))
            & (b(q4[i]) | b(q12[i]))
            & (b(q5[i]) | b(q13[i]))
            & (b(q6[i]) | b(q14[i]))
            & (b(q7[i]) | b(q15[i]));
        let dark = (d(q0[i]) | d(q8[i]))
            & (d(q1[i]) | d(q9[i]))
            & (d(q2[i]) | d(q10[i]))
            & (d(q3[i]) | d(q11[i]))
            & (d(q4[i]) | d(q12[i]))
            & (d(q5[i]) | d(q13[i]))
            & (d(q6[i]) | d(q14[i]))
            & (d(q7[i]) | d(q15[i]));
        flags[i] = bright | dark;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(w: usize, h: usize, f: impl Fn(usize, usize) -> u8) -> Plane {
        let mut data = vec![0; w * h];
        for y in 0..h {
            for x in 0..w {
                data[y * w + x] = f(x, y);
            }
        }
        Plane { w, h, data }
    }

    #[test]
    fn bright_square_corner_detected_once() {
        // A bright quadrant: its corner is a FAST corner (darker arc of > 9 pixels around it).
        // Blurred so that the corner score has a unique maximum (equal scores suppress each
        // other under the strict non-maximum test).
        let sharp = plane(40, 40, |x, y| if x >= 20 && y >= 20 { 200 } else { 20 });
        let img = super::super::imgproc::gaussian_blur(&sharp, 1, 0.8);
        let mut s = FastScratch::default();
        let mut out = Vec::new();
        detect_roi(&img, (0, 0, 40, 40), 20, &mut s, &mut out);
        assert!(!out.is_empty());
        for c in &out {
            assert!(
                (18..=22).contains(&c.x) && (18..=22).contains(&c.y),
                "{c:?}"
            );
            assert!(c.score >= 20);
        }
        // Non-max suppression leaves isolated corners only.
        for a in &out {
            for b in &out {
                if a != b {
                    assert!(a.x.abs_diff(b.x) > 1 || a.y.abs_diff(b.y) > 1);
                }
            }
        }
    }

    #[test]
    fn uniform_and_straight_edges_have_no_corners() {
        let mut s = FastScratch::default();
        let mut out = Vec::new();
        detect_roi(
            &plane(30, 30, |_, _| 90),
            (0, 0, 30, 30),
            7,
            &mut s,
            &mut out,
        );
        assert!(out.is_empty());
        let edge = plane(30, 30, |x, _| if x < 15 { 0 } else { 255 });
        detect_roi(&edge, (0, 0, 30, 30), 7, &mut s, &mut out);
        assert!(out.is_empty(), "{out:?}");
    }

    #[test]
    fn avx2_and_baseline_detection_agree() {
        // Textured noise, blurred a little so corners have unique maxima.
        // A hash of the position as noise.
        let noise = plane(97, 61, |x, y| {
            let h = ((x as u64) << 32 | y as u64)
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (h.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 56) as u8
        });
        let img = super::super::imgproc::gaussian_blur(&noise, 1, 0.6);
        let (mut s1, mut s2) = (FastScratch::default(), FastScratch::default());
        let (mut a, mut b) = (Vec::new(), Vec::new());
        let mut found = 0;
        for (roi, th) in [
            ((0, 0, 97, 61), 7),
            ((5, 3, 70, 40), 20),
            ((11, 9, 97, 61), 12),
        ] {
            detect_roi(&img, roi, th, &mut s1, &mut a);
            detect_roi_body(&img, roi, th, &mut s2, &mut b);
            assert_eq!(a, b, "{roi:?} {th}");
            found += a.len();
        }
        assert!(found > 20, "{found}");
    }

    #[test]
    fn score_is_threshold_monotone() {
        // An isolated bright dot: contrast 100, score must be 99 (largest passing threshold − 1).
        let img = plane(15, 15, |x, y| if (x, y) == (7, 7) { 150 } else { 50 });
        let mut s = FastScratch::default();
        let mut out = Vec::new();
        detect_roi(&img, (0, 0, 15, 15), 20, &mut s, &mut out);
        assert_eq!(out.len(), 1);
        assert_eq!((out[0].x, out[0].y, out[0].score), (7, 7, 99));
        detect_roi(&img, (0, 0, 15, 15), 100, &mut s, &mut out);
        assert!(out.is_empty());
    }
}
