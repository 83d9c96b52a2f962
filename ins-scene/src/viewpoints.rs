//! Where an interactive camera may go in a scene, from four numbers a viewer can send: around a
//! 360° scene (azimuth and elevation about its centre and up direction, a distance, a pan), or,
//! for a forward-facing scene, within the range its spiral covers (beyond it the field was never
//! seen). `render --orbit` and the viewer build cameras here, so a saved view equals a render.

use serde::{Deserialize, Serialize};

use super::camera::{Camera, pose_from_back_up, pose_look_at};
use super::data::{Scene, Split};
use super::geometry::{Mat3, Vec3};
use super::paths::{
    camera_elevations, capture_arc, plane_basis, scene_orbit, scene_up, spiral_frame,
};

/// A viewer's camera pose.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewerPose {
    /// Degrees around the up axis (forward-facing: sideways, within ±[`FORWARD_RANGE`]).
    pub azimuth: f32,
    /// Degrees above the horizontal plane (forward-facing: upwards, within ±[`FORWARD_RANGE`]).
    pub elevation: f32,
    /// Distance as a multiple of the training cameras' mean distance (forward-facing: 1 ± 0.5
    /// moves along the viewing axis through the spiral's depth range).
    pub distance: f32,
    /// Shift of the looked-at point along the camera's right and up axes, as fractions of the
    /// distance (360° scenes).
    pub pan: [f32; 2],
}

/// Degrees of azimuth or elevation that span a forward-facing scene's spiral radius.
pub const FORWARD_RANGE: f32 = 30.0;
/// Distances a viewer may choose (multiples of the training cameras' mean distance).
pub const DISTANCE_RANGE: (f32, f32) = (0.2, 5.0);
/// Degrees a viewer may turn past the photos: beyond either end of a partial capture's arc, and
/// above the highest or below the lowest training camera.
pub const ARC_MARGIN: f32 = 10.0;
/// Elevations no viewer passes (degrees): at the poles the orbit's up direction is undefined.
pub const POLE: f32 = 89.0;

/// `azimuth` (degrees, any turn) held within `(low, high)` (degrees, `low ≤ high < low + 360`):
/// the same direction written from `low` on where it lies inside, else the nearer end.
pub fn clamp_to_arc(azimuth: f32, (low, high): (f32, f32)) -> f32 {
    let past = (azimuth - low).rem_euclid(360.0);
    let width = high - low;
    if past <= width {
        low + past
    } else if past - width < 360.0 - past {
        high
    } else {
        low
    }
}

/// A scene's viewpoints.
#[derive(Clone, Debug)]
pub enum Viewpoints {
    /// Around a 360° scene.
    Orbit {
        /// The point looked at by default (the bounds' centre).
        center: Vec3,
        /// The training cameras' mean up vector.
        up: Vec3,

        /// Two unit vectors spanning the plane perpendicular to `up`.
        plane: (Vec3, Vec3),
        /// The training cameras' mean distance to `center`.
        radius: f32,
        /// Home pose: the first training camera's azimuth, the mean elevation.
        home: ViewerPose,
        /// Horizontal field of view of the first training camera (radians).
        fov_x: f32,
        /// For a capture that saw one side (DTU), the azimuths its cameras cover, widened by
        /// [`ARC_MARGIN`]: `(low, high)` degrees. Beyond, no photo constrains the field.
        arc: Option<(f32, f32)>,
        /// The training cameras' lowest and highest elevations, widened by [`ARC_MARGIN`] and
        /// held short of the poles: `(low, high)` degrees. Below a turntable's lowest photo
        /// lies what no photo saw (under lego's baseplate).
        elevations: (f32, f32),
    },
    /// Within a forward-facing scene's spiral.
    Forward {
        /// The average camera's centre.
        center: Vec3,
        /// The average camera's rotation.
        rotation: Mat3,
        /// The spiral's radii along the average camera's axes.
        radii: [f32; 3],
        /// The point the spiral looks at.
        focus: Vec3,
        /// The cameras' mean up vector.
        up: Vec3,
        /// Horizontal field of view of the first camera (radians).
        fov_x: f32,
    },
}

fn fov_x(c: &Camera) -> f32 {
    2.0 * (0.5 * c.width as f32 / c.fx).atan()
}

impl Viewpoints {
    /// The viewpoints of `scene` (`None` without training views).
    pub fn for_scene(scene: &Scene) -> Option<Self> {
        let train = scene.split(Split::Train);
        let first = &scene.views.get(*train.first()?)?.camera;
        if scene.forward_facing {
            let (center, rotation, radii, focus) = spiral_frame(scene)?;
            return Some(Self::Forward {
                center,
                rotation,
                radii,
                focus,
                up: scene_up(scene),
                fov_x: fov_x(first),
            });
        }
        let (o, _) = scene_orbit(scene)?;
        let (center, up, radius) = (o.center, o.up, o.radius);
        let plane = plane_basis(up);
        let arc = capture_arc(scene).and_then(|(start, span)| {
            let (start, span) = (start.to_degrees(), span.to_degrees());
            (span + 2.0 * ARC_MARGIN < 360.0)
                .then_some((start - ARC_MARGIN, start + span + ARC_MARGIN))
        });
        let (low, high) = camera_elevations(scene, &o)?;
        let elevations = (
            (low.to_degrees() - ARC_MARGIN).clamp(-POLE, POLE),
            (high.to_degrees() + ARC_MARGIN).clamp(-POLE, POLE),
        );
        Some(Self::Orbit {
            center,
            up,
            plane,
            radius,
            home: ViewerPose {
                azimuth: o.start.to_degrees(),
                elevation: o.elevation.to_degrees(),
                distance: 1.0,
                pan: [0.0, 0.0],
            },
            fov_x: fov_x(first),
            arc,
            elevations,
        })
    }

    /// The azimuths a viewer may take, `(low, high)` degrees, where the capture saw one side.
    pub fn azimuth_range(&self) -> Option<(f32, f32)> {
        match self {
            Self::Orbit { arc, .. } => *arc,
            Self::Forward { .. } => None,
        }
    }

    /// The elevations a viewer may take around a 360° scene or partial capture, `(low, high)`
    /// degrees.
    pub fn elevation_range(&self) -> Option<(f32, f32)> {
        match self {
            Self::Orbit { elevations, .. } => Some(*elevations),
            Self::Forward { .. } => None,
        }
    }

    /// The pose a viewer opens at.
    pub fn home(&self) -> ViewerPose {
        match self {
            Self::Orbit { home, .. } => *home,
            Self::Forward { .. } => ViewerPose {
                azimuth: 0.0,
                elevation: 0.0,
                distance: 1.0,
                pan: [0.0, 0.0],
            },
        }
    }

    /// Whether the scene is seen from the front only.
    pub fn forward_facing(&self) -> bool {
        matches!(self, Self::Forward { .. })
    }

    /// `pose` held within the scene's range (elevations within the photos', distances within
    /// [`DISTANCE_RANGE`], a partial capture's azimuths within its arc, forward-facing offsets
    /// within the spiral).
    pub fn clamp(&self, pose: ViewerPose) -> ViewerPose {
        let finite = |v: f32, d: f32| if v.is_finite() { v } else { d };
        let home = self.home();
        let mut p = ViewerPose {
            azimuth: finite(pose.azimuth, home.azimuth),
            elevation: finite(pose.elevation, home.elevation),
            distance: finite(pose.distance, 1.0).clamp(DISTANCE_RANGE.0, DISTANCE_RANGE.1),
            pan: pose.pan.map(|v| finite(v, 0.0).clamp(-1.0, 1.0)),
        };
        match self {
            Self::Orbit {
                arc, elevations, ..
            } => {
                p.elevation = p.elevation.clamp(elevations.0, elevations.1);
                if let Some(arc) = arc {
                    p.azimuth = clamp_to_arc(p.azimuth, *arc);
                }
            }
            Self::Forward { .. } => {
                p.azimuth = p.azimuth.clamp(-FORWARD_RANGE, FORWARD_RANGE);
                p.elevation = p.elevation.clamp(-FORWARD_RANGE, FORWARD_RANGE);
                p.distance = p.distance.clamp(0.5, 1.5);
                p.pan = [0.0, 0.0];
            }
        }
        p
    }

    /// The camera of `pose` (clamped) rendering `width × height` with square pixels and the
    /// training camera's horizontal field of view.
    pub fn camera(&self, pose: ViewerPose, width: u32, height: u32) -> Camera {
        let p = self.clamp(pose);
        let (c2w, fov) = match self {
            Self::Orbit {
                center,
                up,
                plane,
                radius,
                fov_x,
                ..
            } => {
                let (az, el) = (p.azimuth.to_radians(), p.elevation.to_radians());
                let dir = (plane.0 * az.cos() + plane.1 * az.sin()) * el.cos() + *up * el.sin();
                let dist = radius * p.distance;
                let eye = *center + dir * dist;
                let base = pose_look_at(eye, *center, *up);
                let right = Vec3::new(base[0][0], base[1][0], base[2][0]);
                let cam_up = Vec3::new(base[0][1], base[1][1], base[2][1]);
                let shift = (right * p.pan[0] + cam_up * p.pan[1]) * dist;
                (pose_look_at(eye + shift, *center + shift, *up), *fov_x)
            }
            Self::Forward {
                center,
                rotation,
                radii,
                focus,
                up,
                fov_x,
            } => {
                let local = Vec3::new(
                    p.azimuth / FORWARD_RANGE * radii[0],
                    p.elevation / FORWARD_RANGE * radii[1],
                    (p.distance - 1.0) * 2.0 * radii[2],
                );
                let c = *center + *rotation * local;
                (
                    pose_from_back_up((c - *focus).normalize_or_zero(), *up, c),
                    *fov_x,
                )
            }
        };
        Camera::from_fov_x(width.max(1), height.max(1), fov, c2w)
    }
}
#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::synthetic::{SynthOptions, write_blender, write_dtu, write_llff};
    use crate::data::{LoadOptions, Scene};
    use crate::paths::turntable_for_scene;

    fn load(
        write: fn(
            &std::path::Path,
            &SynthOptions,
        ) -> Result<crate::data::synthetic::SynthScene, crate::data::DataError>,
    ) -> (tempfile::TempDir, Scene) {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), &SynthOptions { size: 16, views: 8 }).unwrap();
        let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
        (dir, scene)
    }

    fn close(a: &[[f32; 4]; 3], b: &[[f32; 4]; 3]) -> bool {
        a.iter()
            .flatten()
            .zip(b.iter().flatten())
            .all(|(x, y)| (x - y).abs() < 1e-4)
    }

    #[test]
    fn the_home_view_of_a_360_scene_is_the_turntables_first_frame() {
        let (_d, scene) = load(write_blender);
        let vp = Viewpoints::for_scene(&scene).unwrap();
        assert!(!vp.forward_facing());
        let first = &turntable_for_scene(&scene, 4).unwrap()[0];
        let cam = vp.camera(vp.home(), first.width, first.height);
        assert!(
            close(&cam.c2w, &first.c2w),
            "{:?} vs {:?}",
            cam.c2w,
            first.c2w
        );
        assert!((cam.fx - first.fx).abs() < 1e-3 * first.fx);
        // A quarter turn moves the eye a quarter of the way round the centre, same distance.
        let mut p = vp.home();
        p.azimuth += 90.0;
        let turned = vp.camera(p, 16, 16);
        let c = scene.bounds.center();
        let (a, b) = (cam.origin() - c, turned.origin() - c);
        assert!((a.length() - b.length()).abs() < 1e-4);
        // Same height; the horizontal parts at right angles.
        let up = crate::paths::scene_up(&scene);
        assert!((a.dot(up) - b.dot(up)).abs() < 1e-4);
        let (ha, hb) = (a - up * a.dot(up), b - up * b.dot(up));
        assert!(ha.dot(hb).abs() < 1e-3 * ha.length_squared(), "{ha} {hb}");
    }

    #[test]
    fn panning_moves_eye_and_target_together_and_zoom_scales_the_distance() {
        let (_d, scene) = load(write_blender);
        let vp = Viewpoints::for_scene(&scene).unwrap();
        let home = vp.home();
        let a = vp.camera(home, 16, 16);
        let b = vp.camera(
            ViewerPose {
                pan: [0.2, -0.1],
                ..home
            },
            16,
            16,
        );
        assert!(close(
            &[a.c2w[0], a.c2w[1], a.c2w[2]].map(|r| [r[0], r[1], r[2], 0.0]),
            &b.c2w.map(|r| [r[0], r[1], r[2], 0.0])
        ));
        assert!((a.origin() - b.origin()).length() > 0.1);
        let far = vp.camera(
            ViewerPose {
                distance: 2.0,
                ..home
            },
            16,
            16,
        );
        let c = scene.bounds.center();
        let ratio = (far.origin() - c).length() / (a.origin() - c).length();
        assert!((ratio - 2.0).abs() < 1e-3, "{ratio}");
        // Out-of-range and non-finite requests are held in range.
        let p = vp.clamp(ViewerPose {
            azimuth: f32::NAN,
            elevation: 120.0,
            distance: 100.0,
            pan: [5.0, 0.0],
        });
        assert_eq!(
            (p.azimuth, p.elevation, p.distance, p.pan[0]),
            (
                home.azimuth,
                vp.elevation_range().unwrap().1,
                DISTANCE_RANGE.1,
                1.0
            )
        );
    }

    #[test]
    fn forward_facing_views_stay_within_the_spiral() {
        let (_d, scene) = load(write_llff);
        let vp = Viewpoints::for_scene(&scene).unwrap();
        assert!(vp.forward_facing());
        let Viewpoints::Forward { center, radii, .. } = &vp else {
            unreachable!()
        };
        let far = vp.camera(
            ViewerPose {
                azimuth: 500.0,
                elevation: -500.0,
                distance: 9.0,
                pan: [0.0; 2],
            },
            16,
            16,
        );
        let reach = (radii[0].powi(2) + radii[1].powi(2) + radii[2].powi(2)).sqrt();
        assert!((far.origin() - *center).length() <= reach * 1.001 + 1e-6);
        assert!((vp.camera(vp.home(), 16, 16).origin() - *center).length() < 1e-5);
    }

    #[test]
    fn an_azimuth_is_held_to_an_arc_by_its_nearer_end() {
        let arc = (-70.0, 100.0);
        assert_eq!(clamp_to_arc(0.0, arc), 0.0);
        // The same directions written another turn round.
        assert_eq!(clamp_to_arc(360.0 + 30.0, arc), 30.0);
        assert_eq!(clamp_to_arc(-400.0, arc), -40.0);
        // Outside: the nearer end (the gap from 100 round to 290 = -70 is split at 195).
        assert_eq!(clamp_to_arc(150.0, arc), 100.0);
        assert_eq!(clamp_to_arc(250.0, arc), -70.0);
        assert_eq!(clamp_to_arc(-100.0, arc), -70.0);
    }

    #[test]
    fn a_capture_that_saw_one_side_is_orbited_over_that_side_only() {
        let (_d, scene) = load(write_dtu);
        let vp = Viewpoints::for_scene(&scene).unwrap();
        let (low, high) = vp.azimuth_range().expect("a partial capture has an arc");
        // The arc the training cameras cover (their 150° of the writer's azimuths, seen about
        // the orbit's own axis), 10° more each side.
        let (_, span) = capture_arc(&scene).unwrap();
        assert!(span.to_degrees() < 150.0, "{}", span.to_degrees());
        assert!(
            (high - low - span.to_degrees() - 2.0 * ARC_MARGIN).abs() < 1e-3,
            "{low} {high}"
        );
        let home = vp.home();
        assert_eq!(
            vp.clamp(home).azimuth,
            clamp_to_arc(home.azimuth, (low, high))
        );
        assert!((low..=high).contains(&vp.clamp(home).azimuth));
        // The training cameras' azimuths about the orbit's centre, as the viewer measures them.
        let Viewpoints::Orbit {
            center, up, plane, ..
        } = &vp
        else {
            unreachable!()
        };
        let azimuth = |eye: Vec3| {
            let v = eye - *center;
            v.dot(plane.1).atan2(v.dot(plane.0)).to_degrees()
        };
        let seen: Vec<f32> = scene
            .split(Split::Train)
            .iter()
            .map(|&i| azimuth(scene.views[i].camera.origin()))
            .collect();
        let nearest_seen = |a: f32| {
            seen.iter()
                .map(|s| {
                    let d = (a - s).rem_euclid(360.0);
                    d.min(360.0 - d)
                })
                .fold(f32::INFINITY, f32::min)
        };
        // Asked for every direction round the object, the viewer never looks from further than
        // the margin beyond a photo.
        for k in 0..36 {
            let pose = ViewerPose {
                azimuth: k as f32 * 10.0,
                ..home
            };
            let eye = vp.camera(pose, 16, 16).origin();
            let off = nearest_seen(azimuth(eye));
            assert!(
                off <= ARC_MARGIN + 0.5,
                "azimuth {}: {off}° from a photo",
                k * 10
            );
            // Height above the centre as asked: only the azimuth was held.
            let el = (eye - *center)
                .normalize_or_zero()
                .dot(*up)
                .asin()
                .to_degrees();
            assert!(
                (el - home.elevation).abs() < 0.1,
                "{el} vs {}",
                home.elevation
            );
        }
        // A scene photographed all round has no arc.
        let (_d, scene) = load(write_blender);
        assert_eq!(Viewpoints::for_scene(&scene).unwrap().azimuth_range(), None);
    }

    #[test]
    fn a_turntable_is_not_looked_at_from_below_its_lowest_photo() {
        let (_d, scene) = load(write_blender);
        let vp = Viewpoints::for_scene(&scene).unwrap();
        let Viewpoints::Orbit { center, up, .. } = &vp else {
            unreachable!()
        };
        let elevation = |eye: Vec3| {
            (eye - *center)
                .normalize_or_zero()
                .dot(*up)
                .asin()
                .to_degrees()
        };
        let seen: Vec<f32> = scene
            .split(Split::Train)
            .iter()
            .map(|&i| elevation(scene.views[i].camera.origin()))
            .collect();
        let lowest = seen.iter().copied().fold(f32::INFINITY, f32::min);
        let highest = seen.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        // The writer's cameras sit 10° to 60° above the table: nothing saw it from below.
        assert!(lowest > 5.0 && highest < 65.0, "{lowest} {highest}");
        let (low, high) = vp.elevation_range().unwrap();
        assert!(
            (low - (lowest - ARC_MARGIN)).abs() < 1e-3,
            "{low} vs {lowest}"
        );
        assert!(
            (high - (highest + ARC_MARGIN)).abs() < 1e-3,
            "{high} vs {highest}"
        );
        let home = vp.home();
        for k in -9..=9 {
            let asked = k as f32 * 10.0;
            let eye = vp
                .camera(
                    ViewerPose {
                        elevation: asked,
                        ..home
                    },
                    16,
                    16,
                )
                .origin();
            let el = elevation(eye);
            assert!(
                el >= lowest - ARC_MARGIN - 0.1 && el <= highest + ARC_MARGIN + 0.1,
                "asked {asked}°, looked from {el}° (photos {lowest}° to {highest}°)"
            );
            // Within the range, the elevation asked.
            if (low..=high).contains(&asked) {
                assert!((el - asked).abs() < 0.1, "asked {asked}°, got {el}°");
            }
        }
        // The home view keeps its elevation.
        assert_eq!(vp.clamp(home).elevation, home.elevation);
    }
}
