//! What an exposure takes and books: a shot's or a pulse's image (`acquire`, with the
//! automatic brightness control's metering and the steel it shows), a change while live imaged
//! at its pulse, and the dose and fluoroscopy time of shots and live runs.

use glam::DVec3;
use sim_core::fluoro::brightness::{FrameExposure, Technique, magnification_target_factor};

use super::steel::simplify_polyline;
use super::{
    AcquiredImage, FluoroModality, NeedleShaft, SHOT_EXPOSURE_MS, brightness, dose, pulse, scatter,
};
use crate::session::hands::{MARKER_LENGTH_MM, MARKER_RADIUS_MM};
use crate::session::world::World;

impl FluoroModality {
    /// Fluoroscopy time including a live run still going at `now_ms`, ms.
    pub fn exposure_ms_at(&self, now_ms: u64) -> u64 {
        self.state.exposure_ms
            + self
                .state
                .live_since_ms
                .map_or(0, |s| now_ms.saturating_sub(s))
    }

    /// The fraction of the continuous beam a live second delivers at the session's pulse rate.
    pub(super) fn live_duty(&self) -> f64 {
        pulse::duty(self.state.pulse_rate_pps)
    }

    /// A change while live runs: imaged now if a pulse is due, else by the next pulse (see
    /// [`pulse`]); nothing without live fluoroscopy (last-image hold).
    pub(super) fn live_change(&mut self, world: &World) {
        let Some(since) = self.state.live_since_ms else {
            return;
        };
        let last = self.state.images.last().map(|i| i.t_ms);
        if pulse::pulse_due(self.state.pulse_rate_pps, since, last, world.clock_ms) {
            self.state.pulse_pending = false;
            self.acquire(world, true);
        } else {
            self.state.pulse_pending = true;
        }
    }

    /// Books the live fluoroscopy since the last booking with the current pose and technique.
    pub(super) fn book_live(&mut self, world: &World) {
        // A snapshot written before dose booking existed has a live run without a booking
        // mark: its run is booked from its start.
        let mark = self
            .state
            .dose
            .live_booked_to_ms
            .or(self.state.live_since_ms);
        if let Some(t0) = mark {
            let p = self.projection();
            let seconds = world.clock_ms.saturating_sub(t0) as f64 / 1000.0;
            // A live second carries `duty` of the continuous beam's charge (see `pulse`).
            let (kvp, ma) = (self.state.kvp, self.state.ma * self.live_duty());
            self.state.dose.book(&world.region, &p, kvp, ma, seconds);
            self.state.dose.live_booked_to_ms = Some(world.clock_ms);
        }
    }

    /// Air kerma (mGy) and kerma-area product (Gy cm^2) so far, a live run included.
    pub fn dose_at(&self, world: &World) -> (f64, f64) {
        let d = &self.state.dose;
        let mark = d.live_booked_to_ms.or(self.state.live_since_ms);
        let (k, kap) = mark.map_or((0.0, 0.0), |t0| {
            dose::dose_of(
                &world.region,
                &self.projection(),
                self.state.kvp,
                self.state.ma * self.live_duty(),
                world.clock_ms.saturating_sub(t0) as f64 / 1000.0,
            )
        });
        (d.air_kerma_mgy + k, d.kerma_area_product_gycm2 + kap)
    }

    pub(super) fn dose_json(&self, world: &World) -> serde_json::Value {
        let (k, kap) = self.dose_at(world);
        serde_json::json!({
            "air_kerma_mgy": k,
            "kerma_area_product_gycm2": kap,
            "fluoro_time_s": self.exposure_ms_at(world.clock_ms) as f64 / 1000.0,
        })
    }

    /// The steel an image taken now shows: the needle's shaft and the skin marker's rod.
    pub(super) fn instruments(&self, world: &World) -> Option<NeedleShaft> {
        let mut needle = world.needle.as_ref().map(|n| NeedleShaft {
            points_mm: simplify_polyline(
                &n.state
                    .shaft_polyline(2.0)
                    .iter()
                    .map(|p| p.to_array())
                    .collect::<Vec<_>>(),
            ),
            radius_mm: 0.5 * n.state.profile.outer_diameter_mm,
            rods: Vec::new(),
        });
        if let Some(m) = world.hands.marker_mm {
            // The clamp tip lies on the skin along the body axis, raised by its radius towards
            // the tube.
            let m = DVec3::from_array(m);
            let up = -DVec3::from_array(self.projection().frame().normal);
            let centre = m + up * MARKER_RADIUS_MM;
            let half = DVec3::Z * (0.5 * MARKER_LENGTH_MM);
            needle
                .get_or_insert_with(|| NeedleShaft {
                    points_mm: Vec::new(),
                    radius_mm: 0.0,
                    rods: Vec::new(),
                })
                .rods
                .push((
                    [(centre - half).to_array(), (centre + half).to_array()],
                    MARKER_RADIUS_MM,
                ));
        }
        needle
    }

    pub(super) fn acquire(&mut self, world: &World, live: bool) {
        let index = self.state.images.len() as u64;
        let needle = self.instruments(world);
        let projection = self.projection();
        let technique = Technique {
            kvp: self.state.kvp,
            ma: self.state.ma,
        };
        // A live pulse carries a video frame's charge, a shot the current for its exposure.
        let seconds = if live {
            brightness::PULSE_S
        } else {
            SHOT_EXPOSURE_MS as f64 / 1000.0
        };
        let exposure = FrameExposure {
            frame_s: brightness::PULSE_S,
            duty: self.live_duty(),
            source_to_detector_mm: projection.source_to_detector_mm(),
            source_to_skin_mm: dose::source_to_skin_mm(&world.region, &projection),
        };
        let factor = magnification_target_factor(self.state.config.detector_mm, self.field_mm());
        // Sessions recorded before the detector model and the control meter nothing: their
        // images stay as they were recorded (a result's replay compares the whole state).
        let meters = self.state.detector_noise
            || self.state.brightness.is_some()
            || self.state.scatter.is_some();
        let (measured, next, image_scatter) = if meters {
            let metering = self.metering.get(&world.region, &projection);
            let signal =
                scatter::metering_factor(self.state.scatter, metering, technique.kvp, &projection);
            let (measured, next) = brightness::step(
                &mut self.state.brightness,
                metering,
                technique,
                &exposure,
                factor,
                signal,
            );
            let image_scatter = scatter::image_scatter(self.state.scatter, metering);
            (measured, next, image_scatter)
        } else {
            (f64::NAN, None, None)
        };
        self.state.images.push(AcquiredImage {
            index,
            t_ms: world.clock_ms,
            projection,
            kvp: technique.kvp,
            ma: technique.ma,
            live,
            needle,
            noise_seed: sim_core::rng::splitmix64(
                self.state.seed ^ index.wrapping_mul(sim_core::rng::GOLDEN_GAMMA),
            ),
            iodine_version: world.iodine.as_ref().map(|_| world.iodine_version),
            mas: self.state.detector_noise.then_some(technique.ma * seconds),
            detector_kerma_ngy: measured.is_finite().then_some(measured),
            run: live
                .then_some(self.state.live_runs)
                .filter(|_| self.state.temporal.is_some()),
            filter: self.state.temporal.filter(|_| live).map(|t| t.level),
            scatter: image_scatter,
        });
        self.image_iodine = world.iodine.clone();
        if let Some(next) = next {
            // A live run so far is booked at the technique it ran with.
            self.book_live(world);
            self.state.kvp = next.kvp;
            self.state.ma = next.ma;
            // While live runs, the next pulse images the new technique (the control converges
            // in a still scene too), at a logged moment like every pulse.
            if live {
                self.state.pulse_pending = true;
            }
        }
    }
}
