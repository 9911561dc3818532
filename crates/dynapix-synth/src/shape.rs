//! Analytic primitives of the ray caster: quads, boxes, spheres, capped cylinders, capsules
//! and the inside of the room box. Each primitive lives in its own local frame (an
//! isometry local→world), so textures are attached to the surface and move with it — which is
//! what makes ground-truth flow of movers exact.

use nalgebra::{Isometry3, Point3, Vector3};

/// Shape of a primitive in its local frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// Two-sided rectangle in the local `z = 0` plane, `|x| ≤ hx`, `|y| ≤ hy`.
    Quad {
        /// Half extents `(hx, hy)` in metres.
        half: [f32; 2],
    },
    /// Box `|x| ≤ hx, |y| ≤ hy, |z| ≤ hz`.
    Box {
        /// Half extents in metres.
        half: Vector3<f32>,
    },
    /// Sphere of radius `r` at the local origin.
    Sphere {
        /// Radius in metres.
        r: f32,
    },
    /// Capped cylinder of radius `r` along local z, `|z| ≤ half_h`.
    Cylinder {
        /// Radius in metres.
        r: f32,
        /// Half height in metres.
        half_h: f32,
    },
    /// Capsule: cylinder of radius `r` along local z, `|z| ≤ half_h`, with hemispherical ends.
    Capsule {
        /// Radius in metres.
        r: f32,
        /// Half length of the straight part in metres.
        half_h: f32,
    },
    /// The inside of a box (room): rays from inside hit the walls; normals point inwards.
    RoomInside {
        /// Half extents in metres.
        half: Vector3<f32>,
    },
}

/// Surface attributes at a hit point, in local coordinates.
#[derive(Clone, Copy, Debug)]
pub struct Surface {
    /// Unit normal in the local frame.
    pub normal: Vector3<f32>,
    /// Surface coordinates in metres (u, v), continuous across a face.
    pub uv: [f32; 2],
    /// Face index (boxes/room: 0..6 = ±x, ±y, ±z; cylinders: 0 side, 1 caps; else 0).
    pub face: u8,
    /// Length of the closed u direction of round surfaces (m), 0 for open surfaces; lets the
    /// shader fit a whole number of texture tiles around so that there is no seam.
    pub circumference: f32,
}

impl Shape {
    /// Nearest ray parameter `t > t_min` where `o + t·d` (local frame, `d` not necessarily
    /// unit) meets the surface.
    #[inline]
    pub fn intersect(&self, o: &Vector3<f32>, d: &Vector3<f32>, t_min: f32) -> Option<f32> {
        match *self {
            Shape::Quad { half } => {
                if d.z.abs() < 1e-12 {
                    return None;
                }
                let t = -o.z / d.z;
                if t <= t_min {
                    return None;
                }
                let x = o.x + t * d.x;
                let y = o.y + t * d.y;
                (x.abs() <= half[0] && y.abs() <= half[1]).then_some(t)
            }
            Shape::Box { half } => {
                let (t0, t1) = slab(o, d, &half)?;
                if t0 > t_min {
                    Some(t0)
                } else if t1 > t_min {
                    Some(t1)
                } else {
                    None
                }
            }
            Shape::RoomInside { half } => {
                let (_, t1) = slab(o, d, &half)?;
                (t1 > t_min).then_some(t1)
            }
            Shape::Sphere { r } => sphere(o, d, r, t_min),
            Shape::Cylinder { r, half_h } => {
                let mut best = cylinder_side(o, d, r, half_h, t_min);
                if d.z.abs() > 1e-12 {
                    for zc in [-half_h, half_h] {
                        let t = (zc - o.z) / d.z;
                        if t > t_min && best.is_none_or(|b| t < b) {
                            let x = o.x + t * d.x;
                            let y = o.y + t * d.y;
                            if x * x + y * y <= r * r {
                                best = Some(t);
                            }
                        }
                    }
                }
                best
            }
            Shape::Capsule { r, half_h } => {
                let mut best = cylinder_side(o, d, r, half_h, t_min);
                for zc in [-half_h, half_h] {
                    let oc = o - Vector3::new(0.0, 0.0, zc);
                    if let Some(t) = sphere(&oc, d, r, t_min)
                        && best.is_none_or(|b| t < b)
                    {
                        best = Some(t);
                    }
                }
                best
            }
        }
    }

    /// Normal, surface coordinates and face at local point `p` on the surface.
    pub fn surface(&self, p: &Vector3<f32>) -> Surface {
        match *self {
            Shape::Quad { half } => Surface {
                normal: Vector3::z(),
                uv: [p.x + half[0], half[1] - p.y],
                face: 0,
                circumference: 0.0,
            },
            Shape::Box { half } | Shape::RoomInside { half } => {
                let inside = matches!(self, Shape::RoomInside { .. });
                let q = [p.x / half.x, p.y / half.y, p.z / half.z];
                let mut axis = 0;
                for k in 1..3 {
                    if q[k].abs() > q[axis].abs() {
                        axis = k;
                    }
                }
                let sign = if q[axis] >= 0.0 { 1.0 } else { -1.0 };
                let mut n = Vector3::zeros();
                n[axis] = if inside { -sign } else { sign };
                let s = p + half;
                // Texture axes: horizontal first, vertical (local z, pointing down the image) second.
                let uv = match axis {
                    0 => [s.y, 2.0 * half.z - s.z],
                    1 => [s.x, 2.0 * half.z - s.z],
                    _ => [s.x, s.y],
                };
                Surface {
                    normal: n,
                    uv,
                    face: (2 * axis + usize::from(sign < 0.0)) as u8,
                    circumference: 0.0,
                }
            }
            Shape::Sphere { r } => {
                let n = p / r;
                let phi = n.y.atan2(n.x);
                let theta = n.z.clamp(-1.0, 1.0).acos();
                Surface {
                    normal: n,
                    uv: [phi * r, theta * r],
                    face: 0,
                    circumference: std::f32::consts::TAU * r,
                }
            }
            Shape::Cylinder { r, half_h } => {
                if p.z.abs() >= half_h - 1e-4 * half_h.max(1e-3)
                    && p.x * p.x + p.y * p.y < r * r * 0.999
                {
                    Surface {
                        normal: Vector3::new(0.0, 0.0, p.z.signum()),
                        uv: [p.x + r, p.y + r],
                        face: 1,
                        circumference: 0.0,
                    }
                } else {
                    Surface {
                        normal: Vector3::new(p.x / r, p.y / r, 0.0),
                        uv: [p.y.atan2(p.x) * r, half_h - p.z],
                        face: 0,
                        circumference: std::f32::consts::TAU * r,
                    }
                }
            }
            Shape::Capsule { r, half_h } => {
                let zc = p.z.clamp(-half_h, half_h);
                let n = (p - Vector3::new(0.0, 0.0, zc)) / r;
                Surface {
                    normal: n,
                    uv: [n.y.atan2(n.x) * r, half_h - p.z],
                    face: 0,
                    circumference: std::f32::consts::TAU * r,
                }
            }
        }
    }

    /// Corners of a local bounding box of the shape.
    pub fn local_corners(&self) -> [Vector3<f32>; 8] {
        let h = match *self {
            Shape::Quad { half } => Vector3::new(half[0], half[1], 0.0),
            Shape::Box { half } | Shape::RoomInside { half } => half,
            Shape::Sphere { r } => Vector3::new(r, r, r),
            Shape::Cylinder { r, half_h } => Vector3::new(r, r, half_h),
            Shape::Capsule { r, half_h } => Vector3::new(r, r, half_h + r),
        };
        let mut out = [Vector3::zeros(); 8];
        for (i, c) in out.iter_mut().enumerate() {
            *c = Vector3::new(
                if i & 1 == 0 { -h.x } else { h.x },
                if i & 2 == 0 { -h.y } else { h.y },
                if i & 4 == 0 { -h.z } else { h.z },
            );
        }
        out
    }
}

#[inline]
fn slab(o: &Vector3<f32>, d: &Vector3<f32>, half: &Vector3<f32>) -> Option<(f32, f32)> {
    let mut t0 = f32::NEG_INFINITY;
    let mut t1 = f32::INFINITY;
    for k in 0..3 {
        let inv = 1.0 / d[k];
        let a = (-half[k] - o[k]) * inv;
        let b = (half[k] - o[k]) * inv;
        let (lo, hi) = if a < b { (a, b) } else { (b, a) };
        // NaN (ray parallel to a slab through its boundary) is ignored by max/min.
        t0 = t0.max(lo);
        t1 = t1.min(hi);
    }
    (t0 <= t1).then_some((t0, t1))
}

#[inline]
fn sphere(o: &Vector3<f32>, d: &Vector3<f32>, r: f32, t_min: f32) -> Option<f32> {
    let a = d.dot(d);
    let b = o.dot(d);
    let c = o.dot(o) - r * r;
    let disc = b * b - a * c;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    let t0 = (-b - s) / a;
    if t0 > t_min {
        return Some(t0);
    }
    let t1 = (-b + s) / a;
    (t1 > t_min).then_some(t1)
}

#[inline]
fn cylinder_side(
    o: &Vector3<f32>,
    d: &Vector3<f32>,
    r: f32,
    half_h: f32,
    t_min: f32,
) -> Option<f32> {
    let a = d.x * d.x + d.y * d.y;
    if a < 1e-12 {
        return None;
    }
    let b = o.x * d.x + o.y * d.y;
    let c = o.x * o.x + o.y * o.y - r * r;
    let disc = b * b - a * c;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    [(-b - s) / a, (-b + s) / a]
        .into_iter()
        .find(|&t| t > t_min && (o.z + t * d.z).abs() <= half_h)
}

/// A placed primitive: shape, local→world pose and material index.
#[derive(Clone, Debug)]
pub struct Primitive {
    /// Geometry in the local frame.
    pub shape: Shape,
    /// Local→world pose.
    pub pose: Isometry3<f32>,
    /// Index into the scene's material table.
    pub material: usize,
}

impl Primitive {
    /// A primitive with the given shape, pose and material.
    pub fn new(shape: Shape, pose: Isometry3<f32>, material: usize) -> Self {
        Self {
            shape,
            pose,
            material,
        }
    }

    /// World-space corners of the local bounding box.
    pub fn world_corners(&self) -> [Point3<f32>; 8] {
        self.shape
            .local_corners()
            .map(|c| self.pose * Point3::from(c))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check_hit(s: Shape, o: Vector3<f32>, d: Vector3<f32>, expect: f32) {
        let t = s.intersect(&o, &d, 1e-4).unwrap_or(f32::NAN);
        assert!((t - expect).abs() < 1e-4, "{s:?}: got {t}, want {expect}");
    }

    #[test]
    fn analytic_hits() {
        let o = Vector3::new(0.0, 0.0, -5.0);
        let d = Vector3::new(0.0, 0.0, 1.0);
        check_hit(Shape::Sphere { r: 1.0 }, o, d, 4.0);
        check_hit(
            Shape::Box {
                half: Vector3::new(1.0, 2.0, 0.5),
            },
            o,
            d,
            4.5,
        );
        check_hit(Shape::Quad { half: [1.0, 1.0] }, o, d, 5.0);
        check_hit(
            Shape::Cylinder {
                r: 0.3,
                half_h: 1.0,
            },
            o,
            d,
            4.0,
        );
        check_hit(
            Shape::Capsule {
                r: 0.3,
                half_h: 1.0,
            },
            o,
            d,
            3.7,
        );
        check_hit(
            Shape::RoomInside {
                half: Vector3::new(3.0, 3.0, 3.0),
            },
            Vector3::zeros(),
            d,
            3.0,
        );
        // Side hits.
        let o2 = Vector3::new(-5.0, 0.0, 0.2);
        let d2 = Vector3::new(2.0, 0.0, 0.0);
        check_hit(
            Shape::Cylinder {
                r: 0.5,
                half_h: 1.0,
            },
            o2,
            d2,
            2.25,
        );
        check_hit(
            Shape::Capsule {
                r: 0.5,
                half_h: 1.0,
            },
            o2,
            d2,
            2.25,
        );
        assert!(
            Shape::Quad { half: [1.0, 1.0] }
                .intersect(&Vector3::new(3.0, 0.0, -1.0), &d, 0.0)
                .is_none()
        );
    }

    #[test]
    fn normals_are_unit_and_outward() {
        let b = Shape::Box {
            half: Vector3::new(1.0, 2.0, 0.5),
        };
        let s = b.surface(&Vector3::new(0.2, -2.0, 0.1));
        assert_eq!(s.normal, Vector3::new(0.0, -1.0, 0.0));
        let r = Shape::RoomInside {
            half: Vector3::new(1.0, 2.0, 3.0),
        };
        assert_eq!(
            r.surface(&Vector3::new(0.2, 0.3, 3.0)).normal,
            Vector3::new(0.0, 0.0, -1.0)
        );
        let c = Shape::Capsule {
            r: 0.5,
            half_h: 1.0,
        };
        let n = c.surface(&Vector3::new(0.0, 0.0, 1.5)).normal;
        assert!((n - Vector3::z()).norm() < 1e-6);
    }
}
