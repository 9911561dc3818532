//! The static indoor room: floor, walls, ceiling and furniture (shelves with books, tables,
//! chairs, a desk with a monitor, boxes, a cabinet, a plant, posters, a rug), each with a
//! procedural texture chosen deterministically from the scene seed, and the lights.
//!
//! World frame: z up, floor at `z = 0`; the room spans `x ∈ [-2.6, 2.6]`, `y ∈ [-2.0, 2.6]`,
//! `z ∈ [0, 2.7]`. The free floor `x ∈ [-1.3, 1.4]`, `y ∈ [-0.5, 1.9]` is kept clear for walking
//! people; the sitting places are the two chairs behind the left table, facing `-y`.

use crate::movers::PersonLook;
use crate::shape::{Primitive, Shape};
use crate::texture::{self, Rgb, Texture, TextureKind};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Surface appearance: a texture, its tile size on the surface and a tint.
#[derive(Clone, Debug)]
pub struct Material {
    /// Index into [`Scene::textures`].
    pub texture: usize,
    /// Metres covered by one texture tile along u and v.
    pub scale: [f32; 2],
    /// Multiplier applied to the texture colour.
    pub tint: Rgb,
}

/// A point light with inverse-square-like falloff (no shadows).
#[derive(Clone, Debug)]
pub struct Light {
    /// Position in the world frame.
    pub position: Point3<f32>,
    /// Intensity at distance 0.
    pub intensity: f32,
    /// Distance at which the intensity halves.
    pub falloff: f32,
}

/// Parameters of the scene generator.
#[derive(Clone, Debug)]
pub struct SceneParams {
    /// Resolution of the big surface textures (floor, walls, ceiling).
    pub big_texture_size: usize,
    /// Resolution of all other textures.
    pub texture_size: usize,
    /// Ambient light term of the Lambertian shading.
    pub ambient: f32,
}

impl SceneParams {
    /// Texture resolutions scaled to the image width (defaults are for 640 px): smaller
    /// images need no finer texture detail than a pixel, and baking is proportionally cheaper.
    pub fn for_width(width: u32) -> Self {
        let d = Self::default();
        let s = width as f64 / 640.0;
        let scaled = |n: usize| {
            ((n as f64 * s).round() as usize)
                .clamp(16, 2048)
                .next_power_of_two()
        };
        Self {
            big_texture_size: scaled(d.big_texture_size),
            texture_size: scaled(d.texture_size),
            ..d
        }
    }
}

impl Default for SceneParams {
    fn default() -> Self {
        Self {
            big_texture_size: 512,
            texture_size: 256,
            ambient: 0.38,
        }
    }
}

/// Static scene plus the material/texture tables shared with the movers.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Static primitives.
    pub prims: Vec<Primitive>,
    /// Material table (static scene and movers).
    pub materials: Vec<Material>,
    /// Texture table.
    pub textures: Vec<Texture>,
    /// Lights.
    pub lights: Vec<Light>,
    /// Ambient term.
    pub ambient: f32,
    /// Axis-aligned bounds of the room `(min, max)`.
    pub room: (Vector3<f32>, Vector3<f32>),
    /// Looks (clothes, skin) available to people.
    pub people: Vec<PersonLook>,
    /// Materials available to flying/passing objects.
    pub objects: Vec<usize>,
}

/// Rotation whose columns are the local x, y, z axes expressed in the world frame.
pub fn frame_from_axes(x: Vector3<f32>, y: Vector3<f32>, z: Vector3<f32>) -> UnitQuaternion<f32> {
    let m = Matrix3::from_columns(&[x, y, z]);
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m))
}

fn iso(t: Vector3<f32>, r: UnitQuaternion<f32>) -> Isometry3<f32> {
    Isometry3::from_parts(Translation3::from(t), r)
}

fn yaw(a: f32) -> UnitQuaternion<f32> {
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a)
}

impl Scene {
    /// Adds a texture of `kind` and a material using it; returns the material index.
    pub fn add_material(
        &mut self,
        kind: TextureKind,
        size: usize,
        scale: [f32; 2],
        rng: &mut ChaCha8Rng,
    ) -> usize {
        let tex = texture::generate(kind, size, rng);
        self.textures.push(tex);
        self.materials.push(Material {
            texture: self.textures.len() - 1,
            scale,
            tint: [1.0; 3],
        });
        self.materials.len() - 1
    }

    /// An empty scene (no primitives, no materials) with the default lights.
    pub fn empty() -> Self {
        let room = (Vector3::new(-2.6, -2.0, 0.0), Vector3::new(2.6, 2.6, 2.7));
        Self {
            prims: Vec::new(),
            materials: Vec::new(),
            textures: Vec::new(),
            lights: vec![
                Light {
                    position: Point3::new(-0.8, 0.2, 2.5),
                    intensity: 0.55,
                    falloff: 3.0,
                },
                Light {
                    position: Point3::new(1.2, -1.2, 2.4),
                    intensity: 0.45,
                    falloff: 3.0,
                },
            ],
            ambient: SceneParams::default().ambient,
            room,
            people: Vec::new(),
            objects: Vec::new(),
        }
    }

    fn push_box(
        &mut self,
        centre: Vector3<f32>,
        half: Vector3<f32>,
        heading: f32,
        material: usize,
    ) {
        self.prims.push(Primitive::new(
            Shape::Box { half },
            iso(centre, yaw(heading)),
            material,
        ));
    }

    /// Adds a quad with centre, in-plane right and up axes (world), half extents.
    fn push_quad(
        &mut self,
        centre: Vector3<f32>,
        right: Vector3<f32>,
        up: Vector3<f32>,
        half: [f32; 2],
        material: usize,
    ) {
        let n = right.cross(&up);
        self.prims.push(Primitive::new(
            Shape::Quad { half },
            iso(centre, frame_from_axes(right, up, n)),
            material,
        ));
    }

    /// Generates the room deterministically from `seed`.
    pub fn generate(seed: u64, params: &SceneParams) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5CE7_E000_0000_0001);
        let mut s = Self::empty();
        s.ambient = params.ambient;
        let big = params.big_texture_size;
        let small = params.texture_size;
        let (lo, hi) = s.room;
        let c = (lo + hi) * 0.5;
        let h = (hi - lo) * 0.5;
        let (x, y, z) = (Vector3::x(), Vector3::y(), Vector3::z());

        // Floor, ceiling, walls: different texture families per surface.
        let floor = s.add_material(TextureKind::Checker, big, [1.2, 1.2], &mut rng);
        let ceiling = s.add_material(TextureKind::Wallpaper, big, [1.5, 1.5], &mut rng);
        let wall_kinds = [
            TextureKind::Brick,
            TextureKind::Wallpaper,
            TextureKind::Mosaic,
            TextureKind::Brick,
        ];
        let walls: Vec<usize> = wall_kinds
            .iter()
            .map(|&k| s.add_material(k, big, [1.3, 1.3], &mut rng))
            .collect();
        s.push_quad(Vector3::new(c.x, c.y, lo.z), x, y, [h.x, h.y], floor);
        s.push_quad(Vector3::new(c.x, c.y, hi.z), x, -y, [h.x, h.y], ceiling);
        // Far wall (y = hi.y) faces -y; near wall faces +y; left (x = lo.x) faces +x; right faces -x.
        s.push_quad(Vector3::new(c.x, hi.y, c.z), x, z, [h.x, h.z], walls[0]);
        s.push_quad(Vector3::new(c.x, lo.y, c.z), -x, z, [h.x, h.z], walls[1]);
        s.push_quad(Vector3::new(lo.x, c.y, c.z), -y, z, [h.y, h.z], walls[2]);
        s.push_quad(Vector3::new(hi.x, c.y, c.z), y, z, [h.y, h.z], walls[3]);

        // Posters: several per wall at eye level, random sizes, non-overlapping slots.
        let walls_geo = [
            (Vector3::new(0.0, hi.y - 0.01, 0.0), x, lo.x, hi.x),
            (Vector3::new(0.0, lo.y + 0.01, 0.0), -x, lo.x, hi.x),
            (Vector3::new(lo.x + 0.01, 0.0, 0.0), -y, lo.y, hi.y),
            (Vector3::new(hi.x - 0.01, 0.0, 0.0), y, lo.y, hi.y),
        ];
        for (wi, (base, right, a, b)) in walls_geo.iter().enumerate() {
            let slots = 6;
            let span = b - a;
            for k in 0..slots {
                if rng.random_bool(0.25) {
                    continue;
                }
                let slot_c = a + span * (k as f32 + 0.5) / slots as f32;
                let w = rng.random_range(0.3..(span / slots as f32 * 0.8).max(0.35));
                let hgt = rng.random_range(0.35..0.8);
                let zc: f32 = rng.random_range(1.3..1.8);
                // Keep posters above the far-wall bookshelf and the right-wall desk.
                let zc = if (wi == 0 && (-0.2..1.8).contains(&slot_c)) || (wi == 3 && slot_c < 1.6)
                {
                    zc.max(1.9 + hgt * 0.5).min(2.55 - hgt * 0.5)
                } else {
                    zc
                };
                // `base` fixes the wall coordinate; the slot sets the position along the wall.
                let mut centre = *base;
                if wi < 2 {
                    centre.x = slot_c;
                } else {
                    centre.y = slot_c;
                }
                centre.z = zc;
                let m = s.add_material(TextureKind::Poster, small, [w, hgt], &mut rng);
                s.push_quad(centre, *right, z, [w * 0.5, hgt * 0.5], m);
            }
        }

        // Rug on the floor.
        let rug = s.add_material(TextureKind::Mosaic, small, [0.8, 0.8], &mut rng);
        s.push_quad(Vector3::new(0.3, 1.0, 0.004), x, y, [1.1, 0.8], rug);

        // Bookshelf against the far wall: frame, shelves and rows of books.
        let wood = s.add_material(TextureKind::Wood, small, [0.8, 0.8], &mut rng);
        let (sx0, sx1, depth, top) = (0.0f32, 1.6f32, 0.35f32, 1.8f32);
        let sy = hi.y - depth * 0.5;
        let scx = (sx0 + sx1) * 0.5;
        let shw = (sx1 - sx0) * 0.5;
        for px in [sx0 + 0.02, sx1 - 0.02] {
            s.push_box(
                Vector3::new(px, sy, top * 0.5),
                Vector3::new(0.02, depth * 0.5, top * 0.5),
                0.0,
                wood,
            );
        }
        let n_shelves = 4;
        for k in 0..=n_shelves {
            let zs = 0.05 + k as f32 * (top - 0.05) / n_shelves as f32;
            s.push_box(
                Vector3::new(scx, sy, zs),
                Vector3::new(shw, depth * 0.5, 0.015),
                0.0,
                wood,
            );
            if k < n_shelves {
                let books =
                    s.add_material(TextureKind::Books, small, [shw * 2.0 - 0.1, 0.35], &mut rng);
                let bh = rng.random_range(0.22..0.34);
                let bd = rng.random_range(0.18..0.28);
                s.push_box(
                    Vector3::new(scx, hi.y - 0.02 - bd * 0.5, zs + 0.015 + bh * 0.5),
                    Vector3::new(shw - 0.05, bd * 0.5, bh * 0.5),
                    0.0,
                    books,
                );
            }
        }

        // Table with four legs behind which two chairs face the camera (sitting places).
        let wood2 = s.add_material(TextureKind::Wood, small, [0.9, 0.9], &mut rng);
        let (tx, ty, thx, thy, tz) = (-1.4f32, 1.45f32, 0.7f32, 0.35f32, 0.74f32);
        s.push_box(
            Vector3::new(tx, ty, tz),
            Vector3::new(thx, thy, 0.02),
            0.0,
            wood2,
        );
        for (dx, dy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
            s.push_box(
                Vector3::new(tx + dx * (thx - 0.05), ty + dy * (thy - 0.05), tz * 0.5),
                Vector3::new(0.03, 0.03, tz * 0.5),
                0.0,
                wood2,
            );
        }
        // Things on the table.
        for k in 0..3 {
            let m = s.add_material(
                [
                    TextureKind::Mosaic,
                    TextureKind::Poster,
                    TextureKind::Checker,
                ][k],
                small,
                [0.3, 0.3],
                &mut rng,
            );
            let hx = rng.random_range(0.06..0.14);
            let hz = rng.random_range(0.04..0.12);
            s.push_box(
                Vector3::new(tx - 0.45 + 0.45 * k as f32, ty - 0.1, tz + 0.02 + hz),
                Vector3::new(hx, rng.random_range(0.06..0.12), hz),
                rng.random_range(-0.5..0.5),
                m,
            );
        }
        let chair = s.add_material(TextureKind::Fabric, small, [0.4, 0.4], &mut rng);
        for cx in [-1.8f32, -1.0] {
            push_chair(
                &mut s,
                Vector3::new(cx, 2.05, 0.0),
                -std::f32::consts::FRAC_PI_2,
                chair,
                wood2,
            );
        }

        // Desk against the right wall with a monitor and a keyboard.
        let desk = s.add_material(TextureKind::Wood, small, [1.0, 1.0], &mut rng);
        let (dx0, dy, dhx, dhy, dz) = (2.2f32, 0.7f32, 0.38f32, 0.7f32, 0.76f32);
        s.push_box(
            Vector3::new(dx0, dy, dz),
            Vector3::new(dhx, dhy, 0.02),
            0.0,
            desk,
        );
        for (ox, oy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
            s.push_box(
                Vector3::new(dx0 + ox * (dhx - 0.04), dy + oy * (dhy - 0.04), dz * 0.5),
                Vector3::new(0.025, 0.025, dz * 0.5),
                0.0,
                desk,
            );
        }
        let screen = s.add_material(TextureKind::Poster, small, [0.56, 0.36], &mut rng);
        s.push_box(
            Vector3::new(2.42, 0.75, dz + 0.32),
            Vector3::new(0.02, 0.28, 0.18),
            0.0,
            screen,
        );
        s.push_box(
            Vector3::new(2.43, 0.75, dz + 0.08),
            Vector3::new(0.03, 0.03, 0.07),
            0.0,
            desk,
        );
        let keys = s.add_material(TextureKind::Mosaic, small, [0.15, 0.15], &mut rng);
        s.push_box(
            Vector3::new(2.1, 0.75, dz + 0.03),
            Vector3::new(0.08, 0.22, 0.012),
            0.0,
            keys,
        );
        let chair2 = s.add_material(TextureKind::Fabric, small, [0.4, 0.4], &mut rng);
        push_chair(&mut s, Vector3::new(1.7, 0.55, 0.0), 0.0, chair2, desk);

        // Stack of cardboard-like boxes near the left wall and the near-left corner.
        for k in 0..5 {
            let m = s.add_material(
                [
                    TextureKind::Poster,
                    TextureKind::Mosaic,
                    TextureKind::Checker,
                    TextureKind::Wood,
                    TextureKind::Poster,
                ][k],
                small,
                [0.45, 0.45],
                &mut rng,
            );
            let hx = rng.random_range(0.15..0.25);
            let hy = rng.random_range(0.15..0.25);
            let hz = rng.random_range(0.12..0.22);
            let (bx, by, bz) = match k {
                0 => (-2.25, -1.2, hz),
                1 => (-2.25, -1.2, 0.0),
                2 => (-2.2, -0.55, hz),
                3 => (-1.6, -1.6, hz),
                _ => (1.4, 2.25, hz),
            };
            let bz = if k == 1 { 0.44 + hz } else { bz };
            s.push_box(
                Vector3::new(bx, by, bz),
                Vector3::new(hx, hy, hz),
                rng.random_range(-0.3..0.3),
                m,
            );
        }

        // Sideboard against the near wall with things on it (seen by the loop and rpy cameras).
        let side = s.add_material(TextureKind::Wood, small, [0.7, 0.7], &mut rng);
        s.push_box(
            Vector3::new(0.7, lo.y + 0.22, 0.4),
            Vector3::new(0.6, 0.2, 0.4),
            0.0,
            side,
        );
        let doors = s.add_material(TextureKind::Books, small, [1.2, 0.6], &mut rng);
        s.push_quad(
            Vector3::new(0.7, lo.y + 0.425, 0.38),
            -x,
            z,
            [0.56, 0.3],
            doors,
        );
        for k in 0..3 {
            let m = s.add_material(
                [
                    TextureKind::Poster,
                    TextureKind::Checker,
                    TextureKind::Mosaic,
                ][k],
                small,
                [0.3, 0.3],
                &mut rng,
            );
            let hz = rng.random_range(0.06..0.16);
            s.push_box(
                Vector3::new(0.3 + 0.4 * k as f32, lo.y + 0.22, 0.8 + hz),
                Vector3::new(
                    rng.random_range(0.06..0.12),
                    rng.random_range(0.06..0.12),
                    hz,
                ),
                rng.random_range(-0.6..0.6),
                m,
            );
        }

        // Cabinet against the left wall with two doors.
        let cab = s.add_material(TextureKind::Wallpaper, small, [0.6, 0.6], &mut rng);
        s.push_box(
            Vector3::new(-2.38, 0.3, 0.55),
            Vector3::new(0.22, 0.45, 0.55),
            0.0,
            cab,
        );
        let knob = s.add_material(TextureKind::Checker, small, [0.05, 0.05], &mut rng);
        for yy in [0.22f32, 0.38] {
            s.prims.push(Primitive::new(
                Shape::Sphere { r: 0.025 },
                iso(Vector3::new(-2.15, yy, 0.75), UnitQuaternion::identity()),
                knob,
            ));
        }

        // Plant in the far-right corner: pot and foliage.
        let pot = s.add_material(TextureKind::Brick, small, [0.4, 0.4], &mut rng);
        let leaves = s.add_material(TextureKind::Fabric, small, [0.3, 0.3], &mut rng);
        s.prims.push(Primitive::new(
            Shape::Cylinder {
                r: 0.18,
                half_h: 0.2,
            },
            iso(Vector3::new(2.25, 2.25, 0.2), UnitQuaternion::identity()),
            pot,
        ));
        s.prims.push(Primitive::new(
            Shape::Sphere { r: 0.33 },
            iso(Vector3::new(2.25, 2.25, 0.72), UnitQuaternion::identity()),
            leaves,
        ));

        // Ceiling lamp.
        let lamp = s.add_material(TextureKind::Wallpaper, small, [0.5, 0.5], &mut rng);
        s.prims.push(Primitive::new(
            Shape::Cylinder {
                r: 0.25,
                half_h: 0.08,
            },
            iso(
                Vector3::new(0.0, 0.5, hi.z - 0.35),
                UnitQuaternion::identity(),
            ),
            lamp,
        ));
        s.prims.push(Primitive::new(
            Shape::Cylinder {
                r: 0.01,
                half_h: 0.14,
            },
            iso(
                Vector3::new(0.0, 0.5, hi.z - 0.13),
                UnitQuaternion::identity(),
            ),
            lamp,
        ));

        // Materials of the movers: four people and six objects.
        for _ in 0..4 {
            let shirt = s.add_material(TextureKind::Fabric, small, [0.35, 0.35], &mut rng);
            let trousers = s.add_material(TextureKind::Fabric, small, [0.3, 0.3], &mut rng);
            let skin = s.add_material(TextureKind::Skin, small, [0.3, 0.3], &mut rng);
            // One tile spans the head: u around (2πr), v from top to bottom (πr).
            let r = 0.115;
            let head = s.add_material(
                TextureKind::Head,
                small,
                [std::f32::consts::TAU * r, std::f32::consts::PI * r],
                &mut rng,
            );
            s.people.push(PersonLook {
                shirt,
                trousers,
                skin,
                head,
            });
        }
        for k in 0..6 {
            let kind = [
                TextureKind::Poster,
                TextureKind::Mosaic,
                TextureKind::Checker,
            ][k % 3];
            let m = s.add_material(kind, small, [0.5, 0.5], &mut rng);
            s.objects.push(m);
        }
        s
    }
}

/// A chair: seat, four legs and a back rest, facing `heading` (radians, 0 = +x).
fn push_chair(s: &mut Scene, at: Vector3<f32>, heading: f32, seat_mat: usize, leg_mat: usize) {
    let r = yaw(heading);
    let place = |v: Vector3<f32>| at + r * v;
    s.push_box(
        place(Vector3::new(0.0, 0.0, 0.45)),
        Vector3::new(0.22, 0.22, 0.025),
        heading,
        seat_mat,
    );
    for (dx, dy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        s.push_box(
            place(Vector3::new(dx * 0.19, dy * 0.19, 0.22)),
            Vector3::new(0.02, 0.02, 0.22),
            heading,
            leg_mat,
        );
    }
    // Back rest behind the seat (local -x is behind when facing +x).
    s.push_box(
        place(Vector3::new(-0.21, 0.0, 0.75)),
        Vector3::new(0.02, 0.21, 0.28),
        heading,
        seat_mat,
    );
}
