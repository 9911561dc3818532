//! The Middlebury colour-wheel picture of a flow (Baker et al., IJCV 2011): hue = direction,
//! saturation = magnitude relative to the largest one; vectors longer than the maximum are
//! darkened. Same wheel (55 colours: 15 red-yellow, 6 yellow-green, 4 green-cyan,
//! 11 cyan-blue, 13 blue-magenta, 6 magenta-red) as the evaluation code of the benchmark.

use crate::FlowField;
use image::{Rgb, RgbImage};

/// Segment lengths of the colour wheel.
const SEGMENTS: [usize; 6] = [15, 6, 4, 11, 13, 6];

fn wheel() -> Vec<[f32; 3]> {
    let mut cols = Vec::with_capacity(SEGMENTS.iter().sum());
    // Each segment ramps one channel while another is saturated.
    let ramps: [(usize, usize, bool); 6] = [
        (0, 1, true),  // red fixed, green up
        (1, 0, false), // green fixed, red down
        (1, 2, true),  // green fixed, blue up
        (2, 1, false), // blue fixed, green down
        (2, 0, true),  // blue fixed, red up
        (0, 2, false), // red fixed, blue down
    ];
    for (len, (fixed, moving, up)) in SEGMENTS.iter().zip(ramps) {
        for i in 0..*len {
            let t = (255.0 * i as f32 / *len as f32).floor() / 255.0;
            let mut c = [0.0f32; 3];
            c[fixed] = 1.0;
            c[moving] = if up { t } else { 1.0 - t };
            cols.push(c);
        }
    }
    cols
}

/// Colour of one vector already divided by the normalising radius.
fn color_of(wheel: &[[f32; 3]], u: f32, v: f32) -> [u8; 3] {
    if !u.is_finite() || !v.is_finite() {
        return [0, 0, 0];
    }
    let n = wheel.len();
    let rad = (u * u + v * v).sqrt();
    let a = (-v).atan2(-u) / std::f32::consts::PI;
    let fk = (a + 1.0) / 2.0 * (n - 1) as f32;
    let k0 = (fk.floor() as usize).min(n - 1);
    let k1 = (k0 + 1) % n;
    let f = fk - k0 as f32;
    let mut out = [0u8; 3];
    for c in 0..3 {
        let col = (1.0 - f) * wheel[k0][c] + f * wheel[k1][c];
        let col = if rad <= 1.0 {
            1.0 - rad * (1.0 - col)
        } else {
            col * 0.75
        };
        out[c] = (255.0 * col).round().clamp(0.0, 255.0) as u8;
    }
    out
}

/// Colour picture normalised by the largest finite flow magnitude in the field.
pub fn flow_to_color(flow: &FlowField) -> RgbImage {
    let max = flow
        .data
        .iter()
        .map(|f| (f[0] * f[0] + f[1] * f[1]).sqrt())
        .filter(|m| m.is_finite())
        .fold(0.0f32, f32::max);
    flow_to_color_with_max(flow, max)
}

/// Colour picture normalised by `max_magnitude` (pixels); comparable across fields.
pub fn flow_to_color_with_max(flow: &FlowField, max_magnitude: f32) -> RgbImage {
    let wheel = wheel();
    let norm = if max_magnitude > f32::EPSILON {
        max_magnitude
    } else {
        1.0
    };
    let w = flow.width as usize;
    RgbImage::from_fn(flow.width, flow.height, |x, y| {
        let f = flow
            .data
            .get(y as usize * w + x as usize)
            .copied()
            .unwrap_or([0.0, 0.0]);
        Rgb(color_of(&wheel, f[0] / norm, f[1] / norm))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_is_white_and_directions_follow_the_wheel() {
        let mut f = FlowField::zeros(4, 1);
        f.data[1] = [1.0, 0.0]; // right: red in the Middlebury wheel
        f.data[2] = [0.0, -1.0]; // up (image y points down): blue-magenta
        f.data[3] = [-1.0, 0.0]; // left: cyan
        let img = flow_to_color(&f);
        assert_eq!(img.get_pixel(0, 0).0, [255, 255, 255]);
        let r = img.get_pixel(1, 0).0;
        assert!(r[0] == 255 && r[1] < 10 && r[2] < 10, "{r:?}");
        let c = img.get_pixel(3, 0).0;
        assert!(c[0] < 10 && c[1] > 200 && c[2] > 100, "{c:?}");
        let up = img.get_pixel(2, 0).0;
        assert!(up[2] == 255 && up[1] < 10 && up[0] > 50, "{up:?}");
    }
}
