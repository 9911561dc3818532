//! Procedural textures baked into mip pyramids and sampled trilinearly.
//!
//! ORB (FAST threshold 20 on grey levels) needs stable, high-contrast corners that do not flicker
//! from frame to frame. Texture detail finer than a pixel aliases and makes corners appear and
//! vanish, so every texture is baked once (2×2 supersampled per texel) into a power-of-two mip
//! pyramid and sampled with a level of detail chosen from the pixel footprint on the surface.
//! Generators are deterministic functions of a `ChaCha8Rng` seeded by the scene.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Linear RGB colour with components in `[0, 1]`.
pub type Rgb = [f32; 3];

/// One mip level: `size × size` texels, row-major, 8-bit RGB.
#[derive(Clone, Debug)]
struct MipLevel {
    size: usize,
    data: Vec<[u8; 3]>,
}

/// A square, tileable texture with its mip pyramid.
#[derive(Clone, Debug)]
pub struct Texture {
    levels: Vec<MipLevel>,
}

impl Texture {
    /// Bakes `f(u, v)` (tile coordinates in `[0, 1)`) into a `size × size` texture
    /// (size rounded up to a power of two, at least 4), 2×2 supersampled per texel (the mip
    /// chain does the rest of the prefiltering).
    pub fn bake<F>(size: usize, f: F) -> Self
    where
        F: Fn(f32, f32) -> Rgb + Sync,
    {
        let size = size.max(4).next_power_of_two();
        let inv = 1.0 / size as f32;
        let mut data = vec![[0u8; 3]; size * size];
        data.par_chunks_mut(size).enumerate().for_each(|(y, row)| {
            for (x, texel) in row.iter_mut().enumerate() {
                let mut acc = [0.0f32; 3];
                for sy in 0..2 {
                    for sx in 0..2 {
                        let u = (x as f32 + (sx as f32 + 0.5) / 2.0) * inv;
                        let v = (y as f32 + (sy as f32 + 0.5) / 2.0) * inv;
                        let c = f(u, v);
                        for k in 0..3 {
                            acc[k] += c[k];
                        }
                    }
                }
                for k in 0..3 {
                    texel[k] = to_u8(acc[k] / 4.0);
                }
            }
        });
        let mut levels = vec![MipLevel { size, data }];
        while let Some(prev) = levels.last() {
            if prev.size <= 1 {
                break;
            }
            let s = prev.size / 2;
            let mut d = vec![[0u8; 3]; s * s];
            for y in 0..s {
                for x in 0..s {
                    let mut acc = [0u32; 3];
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let t = prev.data[(2 * y + dy) * prev.size + 2 * x + dx];
                        for k in 0..3 {
                            acc[k] += t[k] as u32;
                        }
                    }
                    d[y * s + x] = [
                        ((acc[0] + 2) / 4) as u8,
                        ((acc[1] + 2) / 4) as u8,
                        ((acc[2] + 2) / 4) as u8,
                    ];
                }
            }
            levels.push(MipLevel { size: s, data: d });
        }
        Self { levels }
    }

    /// Resolution of the finest level (texels per tile side).
    pub fn size(&self) -> usize {
        self.levels[0].size
    }

    /// Trilinear sample at tile coordinates `(u, v)` (wrapping) and level of detail `lod`
    /// (0 = finest level; fractional values blend two levels).
    pub fn sample(&self, u: f32, v: f32, lod: f32) -> Rgb {
        let max = (self.levels.len() - 1) as f32;
        let lod = lod.clamp(0.0, max);
        // lod ≥ 0, so truncation is the floor.
        let l0 = lod as usize;
        let f = lod - l0 as f32;
        let a = self.bilinear(l0, u, v);
        if f <= 0.0 || l0 + 1 >= self.levels.len() {
            return a;
        }
        let b = self.bilinear(l0 + 1, u, v);
        [
            a[0] + (b[0] - a[0]) * f,
            a[1] + (b[1] - a[1]) * f,
            a[2] + (b[2] - a[2]) * f,
        ]
    }

    fn bilinear(&self, level: usize, u: f32, v: f32) -> Rgb {
        let lv = &self.levels[level];
        let s = lv.size;
        let mask = s as i64 - 1;
        let x = u * s as f32 - 0.5;
        let y = v * s as f32 - 0.5;
        let xf = fast_floor(x);
        let yf = fast_floor(y);
        let fx = x - xf as f32;
        let fy = y - yf as f32;
        let x0 = xf & mask;
        let y0 = yf & mask;
        let x1 = (x0 + 1) & mask;
        let y1 = (y0 + 1) & mask;
        let at = |xx: i64, yy: i64| lv.data[(yy as usize) * s + xx as usize];
        let (c00, c10, c01, c11) = (at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1));
        let mut out = [0.0f32; 3];
        for k in 0..3 {
            let top = c00[k] as f32 + (c10[k] as f32 - c00[k] as f32) * fx;
            let bot = c01[k] as f32 + (c11[k] as f32 - c01[k] as f32) * fx;
            out[k] = (top + (bot - top) * fy) * (1.0 / 255.0);
        }
        out
    }
}

/// `floor` as an integer without a libm call (baseline x86-64 has no SSE4.1 `roundss`);
/// exact for |x| < 2^62.
#[inline]
fn fast_floor(x: f32) -> i64 {
    let t = x as i64;
    if (t as f32) > x { t - 1 } else { t }
}

fn to_u8(x: f32) -> u8 {
    (x.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

/// A 32-bit integer hash (lowbias32); used for per-cell random choices inside generators
/// so that a texel's value does not depend on evaluation order.
pub fn hash32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

fn hash2(a: i32, b: i32, seed: u32) -> u32 {
    hash32(
        (a as u32).wrapping_mul(0x9E37_79B9) ^ hash32((b as u32) ^ seed.wrapping_mul(0x85EB_CA6B)),
    )
}

fn unit(h: u32) -> f32 {
    (h >> 8) as f32 / (1u32 << 24) as f32
}

fn mix(a: Rgb, b: Rgb, t: f32) -> Rgb {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

fn scale(a: Rgb, s: f32) -> Rgb {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// Luminance (Rec. 601 weights, as in RGB→grey conversion used by ORB front ends).
pub fn luma(c: Rgb) -> f32 {
    0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]
}

/// A random saturated-ish colour with luminance near `target` (so that pairs of colours chosen
/// with distinct targets keep a grey-level contrast that FAST can see).
pub fn random_colour(rng: &mut ChaCha8Rng, target: f32) -> Rgb {
    let c: Rgb = [
        rng.random::<f32>(),
        rng.random::<f32>(),
        rng.random::<f32>(),
    ];
    let l = luma(c).max(1e-3);
    let s = target / l;
    let mut out = scale(c, s);
    // Pull out-of-range channels back while keeping the luminance roughly on target.
    for _ in 0..4 {
        let over: f32 = out.iter().map(|&x| (x - 1.0).max(0.0)).sum();
        if over <= 0.0 {
            break;
        }
        for x in out.iter_mut() {
            *x = (*x).min(1.0) + over / 3.0 * 0.9;
        }
    }
    [
        out[0].clamp(0.0, 1.0),
        out[1].clamp(0.0, 1.0),
        out[2].clamp(0.0, 1.0),
    ]
}

/// Like [`random_colour`] but mixed towards grey: `sat` = 0 gives grey, 1 the full colour.
pub fn muted_colour(rng: &mut ChaCha8Rng, target: f32, sat: f32) -> Rgb {
    let c = random_colour(rng, target);
    let l = luma(c);
    mix([l; 3], c, sat)
}

/// A colour from a base hue (`base`, any luminance) rescaled to luminance `target`, jittered.
pub fn tinted(rng: &mut ChaCha8Rng, base: Rgb, target: f32, jitter: f32) -> Rgb {
    let j: Rgb = [
        base[0] * (1.0 + rng.random_range(-jitter..=jitter)),
        base[1] * (1.0 + rng.random_range(-jitter..=jitter)),
        base[2] * (1.0 + rng.random_range(-jitter..=jitter)),
    ];
    let s = target / luma(j).max(1e-3);
    [
        (j[0] * s).clamp(0.0, 1.0),
        (j[1] * s).clamp(0.0, 1.0),
        (j[2] * s).clamp(0.0, 1.0),
    ]
}

/// Smooth value noise on a periodic lattice of `period` cells per tile (tileable).
fn value_noise(u: f32, v: f32, period: i32, seed: u32) -> f32 {
    let x = u * period as f32;
    let y = v * period as f32;
    let xi = x.floor();
    let yi = y.floor();
    let fx = x - xi;
    let fy = y - yi;
    let sx = fx * fx * (3.0 - 2.0 * fx);
    let sy = fy * fy * (3.0 - 2.0 * fy);
    let (x0, y0) = (xi as i32, yi as i32);
    let g = |a: i32, b: i32| unit(hash2(a.rem_euclid(period), b.rem_euclid(period), seed));
    let top = g(x0, y0) + (g(x0 + 1, y0) - g(x0, y0)) * sx;
    let bot = g(x0, y0 + 1) + (g(x0 + 1, y0 + 1) - g(x0, y0 + 1)) * sx;
    top + (bot - top) * sy
}

/// Fractal (fBm) tileable noise in `[0, 1]`.
fn fbm(u: f32, v: f32, base: i32, octaves: u32, seed: u32) -> f32 {
    let mut sum = 0.0;
    let mut amp = 0.5;
    let mut norm = 0.0;
    let mut p = base;
    for o in 0..octaves {
        sum += amp * value_noise(u, v, p, seed.wrapping_add(o * 7919));
        norm += amp;
        amp *= 0.5;
        p *= 2;
    }
    sum / norm
}

/// Kinds of procedural texture the scene generator can ask for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TextureKind {
    /// Two-colour checkerboard (floor tiles).
    Checker,
    /// Running-bond bricks with mortar and per-brick colour variation.
    Brick,
    /// Mosaic of square cells with random colours and a grout grid.
    Mosaic,
    /// Poster: background, random rectangles/discs/triangles and rows of text-like blobs.
    Poster,
    /// Wood: noisy stripes with planks.
    Wood,
    /// Wallpaper: regular lattice of diamonds and dots on a noisy background.
    Wallpaper,
    /// Book spines: vertical strips of random widths with horizontal bands.
    Books,
    /// Clothing: stripes or plaid with fabric noise.
    Fabric,
    /// Skin: plain skin tone with soft noise (hands, forearms).
    Skin,
    /// Head: skin tone with hair on the upper part and dark eye/mouth marks.
    Head,
}

/// Generates a texture of the given kind, drawing its parameters from `rng`.
pub fn generate(kind: TextureKind, size: usize, rng: &mut ChaCha8Rng) -> Texture {
    let seed: u32 = rng.random();
    let dark = rng.random_range(0.12..0.3);
    let light = rng.random_range(0.65..0.9);
    let sat = rng.random_range(0.25..0.6);
    let c1 = muted_colour(rng, dark, sat);
    let c2 = muted_colour(rng, light, sat);
    match kind {
        TextureKind::Checker => {
            let n = 2 * rng.random_range(1..=3i32);
            Texture::bake(size, move |u, v| {
                let a = (u * n as f32).floor() as i32 + (v * n as f32).floor() as i32;
                let base = if a.rem_euclid(2) == 0 { c1 } else { c2 };
                scale(base, 0.85 + 0.15 * fbm(u, v, 8, 3, seed))
            })
        }
        TextureKind::Brick => {
            let rows = 2 * rng.random_range(4..=6i32);
            let per_row = rng.random_range(3..=5i32);
            let mortar = muted_colour(rng, light, 0.1);
            let brick = if rng.random_bool(0.6) {
                tinted(rng, [0.62, 0.3, 0.2], dark + 0.12, 0.2)
            } else {
                muted_colour(rng, dark + 0.15, 0.3)
            };
            Texture::bake(size, move |u, v| {
                let y = v * rows as f32;
                let row = y.floor() as i32;
                let off = if row.rem_euclid(2) == 0 { 0.0 } else { 0.5 };
                let x = u * per_row as f32 + off;
                let col = x.floor() as i32;
                let fx = x - x.floor();
                let fy = y - y.floor();
                let gap_x = 0.05;
                let gap_y = 0.1;
                if fx < gap_x || fy < gap_y {
                    return scale(mortar, 0.9 + 0.1 * fbm(u, v, 16, 2, seed));
                }
                let h = hash2(col.rem_euclid(per_row), row, seed);
                let tone = 0.7 + 0.6 * unit(h);
                scale(brick, tone * (0.85 + 0.15 * fbm(u, v, 32, 2, seed ^ 5)))
            })
        }
        TextureKind::Mosaic => {
            let n = rng.random_range(6..=10i32);
            let palette: Vec<Rgb> = (0..6)
                .map(|i| random_colour(rng, 0.15 + 0.13 * i as f32))
                .collect();
            let grout = random_colour(rng, 0.9);
            Texture::bake(size, move |u, v| {
                let x = u * n as f32;
                let y = v * n as f32;
                let (cx, cy) = (x.floor() as i32, y.floor() as i32);
                let (fx, fy) = (x - x.floor(), y - y.floor());
                if fx < 0.08 || fy < 0.08 {
                    return grout;
                }
                let h = hash2(cx, cy, seed);
                palette[(h % palette.len() as u32) as usize]
            })
        }
        TextureKind::Poster => poster(rng, seed, size, c1, c2),
        TextureKind::Wood => {
            let planks = rng.random_range(3..=6i32);
            let c1 = tinted(rng, [0.45, 0.27, 0.13], dark, 0.15);
            let c2 = tinted(rng, [0.75, 0.55, 0.35], light - 0.1, 0.15);
            Texture::bake(size, move |u, v| {
                let p = (v * planks as f32).floor() as i32;
                let fy = v * planks as f32 - p as f32;
                if fy < 0.04 {
                    return scale(c1, 0.5);
                }
                let grain = fbm(u * 0.25, v, 4, 4, seed ^ p as u32);
                let rings = ((grain * 14.0 + u * 3.0).sin() * 0.5 + 0.5).powf(3.0);
                let tone = 0.8 + 0.4 * unit(hash2(p, 0, seed));
                scale(mix(c2, c1, rings * 0.7), tone.min(1.1))
            })
        }
        TextureKind::Wallpaper => {
            let n = rng.random_range(4..=7i32);
            let motif = random_colour(rng, dark);
            let dot = random_colour(rng, 0.45);
            Texture::bake(size, move |u, v| {
                let x = u * n as f32;
                let y = v * n as f32;
                let fx = x - x.floor() - 0.5;
                let fy = y - y.floor() - 0.5;
                let bg = scale(c2, 0.9 + 0.1 * fbm(u, v, 8, 3, seed));
                if fx.abs() + fy.abs() < 0.28 {
                    motif
                } else if (fx.abs() - 0.5).hypot(fy.abs() - 0.5) < 0.1 {
                    dot
                } else {
                    bg
                }
            })
        }
        TextureKind::Books => {
            let n_books = rng.random_range(10..=18i32);
            let palette: Vec<Rgb> = (0..8)
                .map(|i| random_colour(rng, 0.12 + 0.1 * i as f32))
                .collect();
            // Cumulative book edges, irregular widths.
            let mut edges = vec![0.0f32];
            let widths: Vec<f32> = (0..n_books).map(|_| rng.random_range(0.5..1.5)).collect();
            let total: f32 = widths.iter().sum();
            for w in &widths {
                let last = *edges.last().unwrap_or(&0.0);
                edges.push(last + w / total);
            }
            let bands: Vec<(f32, f32)> = (0..n_books)
                .map(|_| (rng.random_range(0.1..0.4), rng.random_range(0.5..0.85)))
                .collect();
            Texture::bake(size, move |u, v| {
                let i = edges
                    .partition_point(|&e| e <= u)
                    .saturating_sub(1)
                    .min(bands.len() - 1);
                let h = hash2(i as i32, 7, seed);
                let c = palette[(h % palette.len() as u32) as usize];
                let (b0, b1) = bands[i];
                let left = edges[i];
                let right = edges[i + 1];
                let w = right - left;
                if (u - left) < 0.06 * w {
                    return scale(c, 0.35);
                }
                if (v - b0).abs() < 0.025 || (v - b1).abs() < 0.025 {
                    return mix(c, [1.0, 0.95, 0.8], 0.8);
                }
                if v > 0.93 {
                    return scale(c, 0.5);
                }
                c
            })
        }
        TextureKind::Fabric => {
            let plaid = rng.random_bool(0.5);
            let n = rng.random_range(3..=8i32);
            Texture::bake(size, move |u, v| {
                let sx = ((u * n as f32).fract() < 0.35) as i32;
                let sy = ((v * n as f32).fract() < 0.35) as i32;
                let k = if plaid { sx + sy } else { sy * 2 };
                let base = match k {
                    0 => c2,
                    1 => mix(c1, c2, 0.5),
                    _ => c1,
                };
                scale(base, 0.85 + 0.15 * fbm(u, v, 32, 2, seed))
            })
        }
        TextureKind::Skin | TextureKind::Head => {
            const TONES: [Rgb; 4] = [
                [0.95, 0.76, 0.62],
                [0.85, 0.62, 0.46],
                [0.62, 0.43, 0.3],
                [0.42, 0.28, 0.2],
            ];
            let tone = TONES[rng.random_range(0..TONES.len())];
            let skin = tinted(rng, tone, luma(tone), 0.05);
            let hair_l = rng.random_range(0.05..0.35);
            let hair = tinted(rng, [0.25, 0.17, 0.1], hair_l, 0.3);
            let head = kind == TextureKind::Head;
            // Head texture spans the sphere once: u around (0.5 = front), v from the top (0) to
            // the bottom (1) of the sphere.
            Texture::bake(size, move |u, v| {
                let n = 0.9 + 0.15 * fbm(u, v, 4, 3, seed);
                if !head {
                    return scale(skin, n);
                }
                let du = u - 0.5;
                let front = du.abs() < 0.22;
                if v < 0.3 || (!front && v < 0.6) {
                    return scale(hair, n);
                }
                let eye = ((du.abs() - 0.07).hypot(v - 0.42)) < 0.025;
                let mouth = du.abs() < 0.06 && (v - 0.62).abs() < 0.015;
                if eye || mouth {
                    return scale(skin, 0.3);
                }
                scale(skin, n)
            })
        }
    }
}

/// A poster: flat background, random shapes and lines of "text" (blobs of words).
fn poster(rng: &mut ChaCha8Rng, seed: u32, size: usize, c1: Rgb, c2: Rgb) -> Texture {
    #[derive(Clone, Copy)]
    enum Sh {
        Rect(f32, f32, f32, f32),
        Disc(f32, f32, f32),
        Tri([f32; 6]),
    }
    let bg = if rng.random_bool(0.5) {
        c2
    } else {
        scale(c2, 0.8)
    };
    let n = rng.random_range(4..=8);
    let mut shapes: Vec<(Sh, Rgb)> = Vec::new();
    for _ in 0..n {
        let target = rng.random_range(0.08..0.5);
        let col = random_colour(rng, target);
        let cx = rng.random_range(0.1..0.9);
        let cy = rng.random_range(0.1..0.6);
        let s = rng.random_range(0.06..0.22);
        let sh = match rng.random_range(0..3) {
            0 => Sh::Rect(cx - s, cy - s * 0.7, cx + s, cy + s * 0.7),
            1 => Sh::Disc(cx, cy, s),
            _ => {
                let mut p = [0.0f32; 6];
                for k in 0..3 {
                    p[2 * k] = cx + rng.random_range(-s..s);
                    p[2 * k + 1] = cy + rng.random_range(-s..s);
                }
                Sh::Tri(p)
            }
        };
        shapes.push((sh, col));
    }
    // Text-like blobs: lines of words below the shapes.
    let text_col = c1;
    let n_lines = rng.random_range(3..=6);
    let mut words: Vec<[f32; 4]> = Vec::new();
    for l in 0..n_lines {
        let y0 = 0.66 + l as f32 * 0.3 / n_lines as f32;
        let hgt = 0.25 / n_lines as f32 * 0.55;
        let mut x = 0.08;
        while x < 0.88 {
            let w = rng.random_range(0.04..0.16);
            if x + w > 0.92 {
                break;
            }
            words.push([x, y0, (x + w), y0 + hgt]);
            x += w + rng.random_range(0.025..0.05);
        }
    }
    let frame = scale(c1, 0.6);
    let _ = seed;
    Texture::bake(size, move |u, v| {
        if !(0.03..=0.97).contains(&u) || !(0.03..=0.97).contains(&v) {
            return frame;
        }
        let mut c = bg;
        for (sh, col) in &shapes {
            let inside = match *sh {
                Sh::Rect(x0, y0, x1, y1) => u >= x0 && u <= x1 && v >= y0 && v <= y1,
                Sh::Disc(cx, cy, r) => (u - cx).hypot(v - cy) <= r,
                Sh::Tri(p) => {
                    let e = |ax: f32, ay: f32, bx: f32, by: f32| {
                        (bx - ax) * (v - ay) - (by - ay) * (u - ax)
                    };
                    let d0 = e(p[0], p[1], p[2], p[3]);
                    let d1 = e(p[2], p[3], p[4], p[5]);
                    let d2 = e(p[4], p[5], p[0], p[1]);
                    (d0 >= 0.0 && d1 >= 0.0 && d2 >= 0.0) || (d0 <= 0.0 && d1 <= 0.0 && d2 <= 0.0)
                }
            };
            if inside {
                c = *col;
            }
        }
        for w in &words {
            if u >= w[0] && u <= w[2] && v >= w[1] && v <= w[3] {
                c = text_col;
            }
        }
        c
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn mip_of_checker_averages_to_grey() {
        let t = Texture::bake(64, |u, v| {
            let a = (u * 8.0).floor() as i32 + (v * 8.0).floor() as i32;
            if a % 2 == 0 { [0.0; 3] } else { [1.0; 3] }
        });
        // Finest level keeps full contrast, coarse levels converge to the mean.
        let fine = t.sample(0.5 / 8.0, 0.5 / 8.0, 0.0);
        assert!(fine[0] < 0.05);
        let coarse = t.sample(0.3, 0.7, 6.0);
        assert!((coarse[0] - 0.5).abs() < 0.02, "{coarse:?}");
    }

    #[test]
    fn generation_is_deterministic() {
        let mut a = ChaCha8Rng::seed_from_u64(3);
        let mut b = ChaCha8Rng::seed_from_u64(3);
        let ta = generate(TextureKind::Poster, 32, &mut a);
        let tb = generate(TextureKind::Poster, 32, &mut b);
        assert_eq!(ta.levels[0].data, tb.levels[0].data);
    }
}
