//! Camera and lens planning for watching the build plate (paper section 2).
//!
//! The camera looks at the plate from a top viewport, so its optical axis is off the plate
//! normal and a conventional lens cannot focus the whole plate. [`plan`] evaluates the paper's
//! equations 1-4 (magnification, hyperfocal distance, near and far depth-of-field limits) for a
//! given stand-off, checks whether the plate fits inside that depth of field, and computes the
//! Scheimpflug tilt that lays the plane of focus on the plate instead. [`plot_svg`] draws the
//! paper's figures 3 and 4 for the same numbers.
//!
//! # Conventions
//!
//! Everything is a thin lens in the side view: the plane that contains the optical axis and the
//! plate normal (the tilt plane). The *lens frame* has its origin at the lens center, `z` along
//! the optical axis toward the plate and `x` along the lens plane inside the tilt plane; the
//! lens plane is `z = 0` and stays perpendicular to the optical axis, the image side is `z < 0`.
//!
//! * The plate is a line through the plate center `C = (0, s)` (the point focused on, at object
//!   distance `s` = `distance_mm`), tilted by `θ` = `angle_deg` from the lens plane, which is the
//!   same as the optical axis being `θ` off the plate normal. Plate coordinate `t` (mm from the
//!   center, `t < 0` toward the camera) sits at `(t cos θ, s + t sin θ)`, so the near and far
//!   edges are at axial distances `s ∓ (L/2) sin θ`.
//! * A point at axial distance `z` images at `-f/(z - f)` times its position; equation 1 applied
//!   at `z`, `M(z) = f / (z - f)`, is therefore the local transverse magnification of a point
//!   that is in focus, which with the Scheimpflug tilt is every plate point. (Without tilt the
//!   sensor stays at `v` and the chief-ray scale is `v / z`: about 1.6 % apart at the paper's
//!   plate edges, e.g. 42.56 instead of 41.89 µm at the near edge for `s` = 500 mm.)
//! * The sensor is `sensor_px = (width, height)` pixels: the width lies across the tilt plane,
//!   the height along it (a landscape body tilted about a horizontal axis).
//! * The Scheimpflug tilt `α` is the angle between the image plane and the lens plane (the
//!   image plane is the one that tilts in this frame). Imaging the plate line through the thin
//!   lens gives an image line of direction `(cos θ (s - f), -f sin θ)`, hence
//!   `tan α = f tan θ / (s - f) = M tan θ`. Image plane, lens plane and plate meet at the
//!   Scheimpflug line `S = (-s cot θ, 0)`.
//! * The hinge line `P` (Merklinger) is where the plane of focus crosses the front focal plane
//!   `z = f`; it also lies on the plane through the lens center parallel to the image plane, at
//!   `J = f / sin α` from the lens center measured along that plane (not along the lens plane),
//!   i.e. at `(-(s - f) cot θ, f)`. The tilted depth of field is the wedge between the planes
//!   through `P` and the axial limits `D_near`, `D_far` of equations 3 and 4 (a ray trace of the
//!   blur on the tilted sensor puts one pixel of blur on these planes to within 2.5 % over the
//!   plate's depth for the paper's setup; see the tests).

mod plot;
#[cfg(test)]
mod tests;

pub use plot::plot_svg;

use std::fmt;

/// Wavelength for the diffraction estimate: green, the middle of the visible band.
pub const WAVELENGTH_UM: f64 = 0.55;

/// What `layerwise optics` is asked about: lens, sensor and where the camera sits.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct OpticsInput {
    /// Focal length `f` in mm.
    pub focal_mm: f64,
    /// f-number `N`; the aperture diameter is `D = f / N`.
    pub f_number: f64,
    /// Pixel pitch `d` (the paper's detector size) in µm.
    pub pixel_um: f64,
    /// Sensor size in pixels, `(width, height)`; the height runs along the tilt plane.
    pub sensor_px: (u32, u32),
    /// Object distance `s` in mm from the lens center to the plate center, along the axis.
    pub distance_mm: f64,
    /// Angle between the optical axis and the plate normal in degrees.
    pub angle_deg: f64,
    /// Side length of the square build plate in mm.
    pub plate_mm: f64,
}

impl OpticsInput {
    /// The paper's camera: Nikon D810 (7360 x 4912, 4.88 µm) with the PC-E Micro NIKKOR 45 mm at
    /// f/32, 30° off-normal over the ProX320's 275 mm plate; the paper gives no stand-off.
    pub fn paper_setup(distance_mm: f64) -> OpticsInput {
        OpticsInput {
            focal_mm: 45.0,
            f_number: 32.0,
            pixel_um: 4.88,
            sensor_px: (7360, 4912),
            distance_mm,
            angle_deg: 30.0,
            plate_mm: 275.0,
        }
    }
}

/// The planned optics. Lengths in mm, resolutions in µm per pixel on the plate.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct OpticsReport {
    /// Equation 1 at the plate center, `M = f / (s - f)`.
    pub magnification: f64,
    /// Thin-lens image distance of the plate center, `v = s f / (s - f)`.
    pub image_distance_mm: f64,
    /// Aperture diameter `D = f / N`.
    pub aperture_mm: f64,
    /// Pixel footprint across the tilt plane at the plate center, `d / M`.
    pub resolution_center_um: f64,
    /// Pixel footprint across the tilt plane at the plate's near edge, `d / M(z_near)`.
    pub resolution_near_um: f64,
    /// Pixel footprint across the tilt plane at the plate's far edge, `d / M(z_far)`.
    pub resolution_far_um: f64,
    /// Foreshortened pixel footprint along the tilt direction at the plate center (in focus):
    /// `d / |dQ/dt|` with `Q(t)` the plate point's image on the tilted image plane.
    pub resolution_along_center_um: f64,
    /// Foreshortened footprint along the tilt direction at the near edge.
    pub resolution_along_near_um: f64,
    /// Foreshortened footprint along the tilt direction at the far edge.
    pub resolution_along_far_um: f64,
    /// Equation 2, `H = D f / d + f`.
    pub hyperfocal_mm: f64,
    /// Equation 3, near limit of the depth of field along the axis.
    pub near_mm: f64,
    /// Equation 4, far limit; `None` (JSON `null`) when infinite, i.e. `s ≥ H`.
    pub far_mm: Option<f64>,
    /// Axial distance of the plate's near edge, `s - (L/2) sin θ`.
    pub plate_near_edge_mm: f64,
    /// Axial distance of the plate's far edge, `s + (L/2) sin θ`.
    pub plate_far_edge_mm: f64,
    /// Both edges within `[near_mm, far_mm]` with the lens untilted.
    pub plate_in_focus_without_tilt: bool,
    /// Scheimpflug angle `α` between image plane and lens plane, `tan α = M tan θ`.
    pub scheimpflug_tilt_deg: f64,
    /// Distance from the lens center to the Scheimpflug line S along the lens plane,
    /// `s cot θ`; `None` when the plate is perpendicular to the axis.
    pub scheimpflug_line_mm: Option<f64>,
    /// Distance from the lens center to the hinge line P, `J = f / sin α`; `None` without tilt.
    pub hinge_distance_mm: Option<f64>,
    /// Field of view `(width, height)` in a plane perpendicular to the axis at `s`.
    pub field_of_view_mm: (f64, f64),
    /// Size of the plate's image on the tilted image plane, `(across, along)`: the near edge's
    /// width and the near-to-far length.
    pub plate_image_mm: (f64, f64),
    /// The whole plate images inside the sensor, centered on the plate center (no shift).
    pub plate_fits_in_view: bool,
    /// Airy disk diameter `2.44 λ N` on the sensor, λ = 0.55 µm.
    pub diffraction_blur_um: f64,
    /// The Airy disk is wider than a pixel: stopping down further only blurs.
    pub diffraction_limited: bool,
}

/// Why the optics cannot be planned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OpticsError {
    #[error("optics: {name} must be a finite positive number, got {value}")]
    NotPositive { name: &'static str, value: f64 },
    #[error("optics: angle must be between 0 and 89 degrees off the plate normal, got {0}")]
    Angle(f64),
    #[error(
        "optics: object distance {distance_mm} mm must exceed the focal length {focal_mm} mm \
         (no real image otherwise)"
    )]
    DistanceWithinFocalLength { distance_mm: f64, focal_mm: f64 },
    #[error(
        "optics: the plate's near edge is {near_edge_mm:.1} mm along the axis, not beyond the \
         focal length {focal_mm} mm: move the camera back or reduce the angle"
    )]
    PlateWithinFocalLength { near_edge_mm: f64, focal_mm: f64 },
    #[error("optics: sensor must be WIDTHxHEIGHT in pixels, e.g. 7360x4912, got {0:?}")]
    Sensor(String),
}

/// Parses `"7360x4912"` (also `X` or `×`, spaces allowed) into `(width, height)`.
pub fn parse_sensor(text: &str) -> Result<(u32, u32), OpticsError> {
    let bad = || OpticsError::Sensor(text.to_string());
    let (w, h) = text.trim().split_once(['x', 'X', '×']).ok_or_else(bad)?;
    let w: u32 = w.trim().parse().map_err(|_| bad())?;
    let h: u32 = h.trim().parse().map_err(|_| bad())?;
    if w == 0 || h == 0 {
        return Err(bad());
    }
    Ok((w, h))
}

fn positive(name: &'static str, value: f64) -> Result<f64, OpticsError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(OpticsError::NotPositive { name, value })
    }
}

/// The side view in the lens frame (see the module docs); shared by [`plan`], the plot and
/// the tests so they all use one geometry.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SideView {
    pub f: f64,
    pub s: f64,
    /// Plate tilt from the lens plane, radians.
    pub theta: f64,
    pub half_plate: f64,
    /// Scheimpflug tilt, radians.
    pub alpha: f64,
}

impl SideView {
    fn new(input: &OpticsInput) -> SideView {
        let f = input.focal_mm;
        let s = input.distance_mm;
        let theta = input.angle_deg.to_radians();
        SideView {
            f,
            s,
            theta,
            half_plate: input.plate_mm / 2.0,
            alpha: (f / (s - f) * theta.tan()).atan(),
        }
    }

    /// Image distance of the plate center.
    pub fn v(&self) -> f64 {
        self.s * self.f / (self.s - self.f)
    }

    /// Plate point at plate coordinate `t` (mm from the center, negative toward the camera).
    pub fn plate_point(&self, t: f64) -> [f64; 2] {
        [t * self.theta.cos(), self.s + t * self.theta.sin()]
    }

    /// Thin-lens image of an object point in front of the focal plane (`z > f`).
    pub fn image_of(&self, p: [f64; 2]) -> [f64; 2] {
        let k = -self.f / (p[1] - self.f);
        [k * p[0], k * p[1]]
    }

    /// Unit direction of the tilted image plane (the image of the plate line).
    pub fn image_plane_dir(&self) -> [f64; 2] {
        [self.alpha.cos(), -self.alpha.sin()]
    }

    /// Scheimpflug line S: plate, lens plane and image plane meet here.
    pub fn scheimpflug_point(&self) -> Option<[f64; 2]> {
        (self.theta > 0.0).then(|| [-self.s / self.theta.tan(), 0.0])
    }

    /// Hinge line P: plane of focus meets the front focal plane.
    pub fn hinge_point(&self) -> Option<[f64; 2]> {
        (self.theta > 0.0).then(|| [-(self.s - self.f) / self.theta.tan(), self.f])
    }

    /// `|dQ/dt|`: image length per plate length along the tilt at the plate point `t`, with
    /// `Q(t) = -f P(t) / (z - f)`; differentiating gives
    /// `dQ/dt = -f (cos θ (s - f), -f sin θ) / (z - f)²`.
    pub fn along_scale(&self, t: f64) -> f64 {
        let z = self.s + t * self.theta.sin();
        let (sin, cos) = self.theta.sin_cos();
        self.f * (cos * (self.s - self.f)).hypot(self.f * sin) / ((z - self.f) * (z - self.f))
    }
}

/// Evaluates equations 1-4, the depth-of-field check and the Scheimpflug tilt for `input`.
pub fn plan(input: &OpticsInput) -> Result<OpticsReport, OpticsError> {
    let f = positive("focal length", input.focal_mm)?;
    let n = positive("f-number", input.f_number)?;
    let pixel_um = positive("pixel pitch", input.pixel_um)?;
    let s = positive("object distance", input.distance_mm)?;
    let plate = positive("plate size", input.plate_mm)?;
    let (width_px, height_px) = input.sensor_px;
    if width_px == 0 || height_px == 0 {
        return Err(OpticsError::Sensor(format!("{width_px}x{height_px}")));
    }
    if !(0.0..=89.0).contains(&input.angle_deg) {
        return Err(OpticsError::Angle(input.angle_deg));
    }
    if s <= f {
        return Err(OpticsError::DistanceWithinFocalLength {
            distance_mm: s,
            focal_mm: f,
        });
    }
    let view = SideView::new(input);
    let sin = view.theta.sin();
    let near_edge = s - plate / 2.0 * sin;
    let far_edge = s + plate / 2.0 * sin;
    if near_edge <= f {
        return Err(OpticsError::PlateWithinFocalLength {
            near_edge_mm: near_edge,
            focal_mm: f,
        });
    }

    let d = pixel_um / 1000.0;
    let magnification = f / (s - f); // eq. 1
    let local_m = |z: f64| f / (z - f);
    let aperture = f / n;
    let hyperfocal = aperture * f / d + f; // eq. 2
    let near = s * (hyperfocal - f) / (hyperfocal + s - 2.0 * f); // eq. 3
    let far = (s < hyperfocal).then(|| s * (hyperfocal - f) / (hyperfocal - s)); // eq. 4
    let plate_in_focus = near_edge >= near && far.is_none_or(|far| far_edge <= far);

    let sensor_w = f64::from(width_px) * d;
    let sensor_h = f64::from(height_px) * d;
    let half = plate / 2.0;
    // The plate image on the tilted image plane, the sensor centered on the plate center.
    let q0 = view.image_of(view.plate_point(0.0));
    let dist = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
    let along_near = dist(view.image_of(view.plate_point(-half)), q0);
    let along_far = dist(view.image_of(view.plate_point(half)), q0);
    let across = plate * local_m(near_edge); // widest at the near edge
    let fits = across <= sensor_w && along_near.max(along_far) <= sensor_h / 2.0;

    let diffraction = 2.44 * WAVELENGTH_UM * n;
    let alpha = view.alpha;
    Ok(OpticsReport {
        magnification,
        image_distance_mm: view.v(),
        aperture_mm: aperture,
        resolution_center_um: pixel_um / magnification,
        resolution_near_um: pixel_um / local_m(near_edge),
        resolution_far_um: pixel_um / local_m(far_edge),
        resolution_along_center_um: pixel_um / view.along_scale(0.0),
        resolution_along_near_um: pixel_um / view.along_scale(-half),
        resolution_along_far_um: pixel_um / view.along_scale(half),
        hyperfocal_mm: hyperfocal,
        near_mm: near,
        far_mm: far,
        plate_near_edge_mm: near_edge,
        plate_far_edge_mm: far_edge,
        plate_in_focus_without_tilt: plate_in_focus,
        scheimpflug_tilt_deg: alpha.to_degrees(),
        scheimpflug_line_mm: view.scheimpflug_point().map(|p| -p[0]),
        hinge_distance_mm: (alpha > 0.0).then(|| f / alpha.sin()),
        field_of_view_mm: (sensor_w / magnification, sensor_h / magnification),
        plate_image_mm: (across, along_near + along_far),
        plate_fits_in_view: fits,
        diffraction_blur_um: diffraction,
        diffraction_limited: diffraction > pixel_um,
    })
}

impl fmt::Display for OpticsReport {
    fn fmt(&self, out: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            out,
            "magnification (eq. 1)        {:.6}  (image distance {:.2} mm, aperture {:.3} mm)",
            self.magnification, self.image_distance_mm, self.aperture_mm
        )?;
        writeln!(
            out,
            "resolution across the tilt   center {:.2} µm/px, near edge {:.2} µm/px, far edge {:.2} µm/px",
            self.resolution_center_um, self.resolution_near_um, self.resolution_far_um
        )?;
        writeln!(
            out,
            "resolution along the tilt    center {:.2} µm/px, near edge {:.2} µm/px, far edge {:.2} µm/px (foreshortened, in focus)",
            self.resolution_along_center_um,
            self.resolution_along_near_um,
            self.resolution_along_far_um
        )?;
        writeln!(
            out,
            "hyperfocal distance (eq. 2)  {:.1} mm",
            self.hyperfocal_mm
        )?;
        match self.far_mm {
            Some(far) => writeln!(
                out,
                "depth of field (eq. 3, 4)    {:.1} mm to {:.1} mm ({:.1} mm deep)",
                self.near_mm,
                far,
                far - self.near_mm
            )?,
            None => writeln!(
                out,
                "depth of field (eq. 3, 4)    {:.1} mm to infinity",
                self.near_mm
            )?,
        }
        writeln!(
            out,
            "plate edges along the axis   near {:.1} mm, far {:.1} mm",
            self.plate_near_edge_mm, self.plate_far_edge_mm
        )?;
        writeln!(
            out,
            "plate in focus without tilt  {}",
            if self.plate_in_focus_without_tilt {
                "yes"
            } else {
                "no"
            }
        )?;
        writeln!(
            out,
            "Scheimpflug tilt             {:.3}° between image plane and lens plane",
            self.scheimpflug_tilt_deg
        )?;
        if let Some(line) = self.scheimpflug_line_mm {
            writeln!(
                out,
                "Scheimpflug line S           {line:.1} mm from the lens center along the lens plane"
            )?;
        }
        if let Some(hinge) = self.hinge_distance_mm {
            writeln!(
                out,
                "hinge line P                 {hinge:.1} mm from the lens center (J = f / sin α)"
            )?;
        }
        writeln!(
            out,
            "field of view at the center  {:.1} x {:.1} mm",
            self.field_of_view_mm.0, self.field_of_view_mm.1
        )?;
        writeln!(
            out,
            "plate image on the sensor    {:.2} x {:.2} mm: {}",
            self.plate_image_mm.0,
            self.plate_image_mm.1,
            if self.plate_fits_in_view {
                "fits"
            } else {
                "does not fit"
            }
        )?;
        write!(
            out,
            "diffraction blur (Airy)      {:.2} µm{}",
            self.diffraction_blur_um,
            if self.diffraction_limited {
                ", wider than a pixel: diffraction-limited"
            } else {
                ""
            }
        )
    }
}
