//! The show's clock in a take: the readings of a DAW's or a show desk's
//! transport the take heard ([`Clock`] records), and the show's time at
//! any instant of the take that they give ([`ShowTrack`]), which an export
//! lines a soundtrack up by.
//!
//! Readings arrive with the jitter of a MIDI cable and a busy machine (a
//! few milliseconds, more under load), so no single one is trusted: the
//! running readings are gathered in runs (the transport playing without a
//! jump, stop or locate), and a run's show time is the take's time plus
//! the median of its readings' differences.

use serde::{Deserialize, Serialize};

/// Where the show's clock (a DAW's or a show desk's transport: MIDI Time
/// Code, MIDI clock, an OSC time message) was when the take heard it:
/// what lines a soundtrack up with the take by the music's time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Clock {
    /// Seconds since the take began, when the reading arrived.
    pub t: f64,
    /// Seconds on the show's clock then.
    pub show: f64,
    /// The transport was running (a parked or located clock says where it
    /// is, not how the take moves against it).
    pub running: bool,
    /// What told it.
    pub source: ClockSource,
}

/// What a [`Clock`] reading came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ClockSource {
    /// MIDI Time Code (quarter frames, full frames).
    TimeCode,
    /// MIDI clock and song position, at the input's tempo.
    MidiClock,
    /// An OSC `/puppetry/clock` message.
    Osc,
}

/// Seconds the show's clock may move against the take's between two
/// readings and still be one run: more is a jump (a locate while playing),
/// far more than a reading's jitter.
const JUMP: f64 = 0.25;

/// One stretch of a take during which the show's clock ran steadily.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Run {
    /// The take's time at its first and last reading.
    from: f64,
    to: f64,
    /// Show time minus take time (the median of the run's readings).
    offset: f64,
    source: ClockSource,
}

/// The show's time along a take, from its [`Clock`] readings.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ShowTrack {
    runs: Vec<Run>,
}

impl ShowTrack {
    /// The track of a take's readings, in the order it recorded them.
    pub fn new(clocks: &[Clock]) -> ShowTrack {
        let mut runs = Vec::new();
        let mut run: Vec<&Clock> = Vec::new();
        let close = |run: &mut Vec<&Clock>, runs: &mut Vec<Run>| {
            if let (Some(first), Some(last)) = (run.first(), run.last()) {
                let mut offsets: Vec<f64> = run.iter().map(|c| c.show - c.t).collect();
                offsets.sort_by(f64::total_cmp);
                runs.push(Run {
                    from: first.t,
                    to: last.t,
                    offset: offsets[offsets.len() / 2],
                    source: first.source,
                });
            }
            run.clear();
        };
        for clock in clocks {
            let jumped = run.last().is_some_and(|last| {
                !clock.running
                    || clock.source != last.source
                    || ((clock.show - clock.t) - (last.show - last.t)).abs() > JUMP
            });
            if jumped {
                close(&mut run, &mut runs);
            }
            if clock.running {
                run.push(clock);
            }
        }
        close(&mut run, &mut runs);
        ShowTrack { runs }
    }

    /// Whether the take heard the show's clock running at all.
    pub fn is_empty(&self) -> bool {
        self.runs.is_empty()
    }

    /// The show's time at the take's second `t`, and what told it: by
    /// the run `t` falls in, else the nearest one (before the first
    /// reading, say, at the take's very start).
    pub fn show_at(&self, t: f64) -> Option<(f64, ClockSource)> {
        let distance = |r: &Run| (r.from - t).max(t - r.to).max(0.0);
        let run = self
            .runs
            .iter()
            .min_by(|a, b| distance(a).total_cmp(&distance(b)))?;
        Some((t + run.offset, run.source))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clock(t: f64, show: f64, running: bool) -> Clock {
        Clock {
            t,
            show,
            running,
            source: ClockSource::TimeCode,
        }
    }

    #[test]
    fn the_median_reading_lines_the_take_up() {
        // A transport at 11 s when the take began, read every 80 ms with
        // a few milliseconds' jitter and one reading late by 60 ms.
        let mut clocks: Vec<Clock> = (1..50)
            .map(|k| {
                let t = k as f64 * 0.08;
                let late = [0.0, 0.003, 0.001, 0.004][k % 4] + if k == 20 { 0.06 } else { 0.0 };
                clock(t + late, 11.0 + t, true)
            })
            .collect();
        clocks.insert(0, clock(0.0, 3.0, false));
        let track = ShowTrack::new(&clocks);
        let (show, source) = track.show_at(0.0).unwrap();
        assert!((show - 11.0).abs() < 0.005, "{show}");
        assert_eq!(source, ClockSource::TimeCode);
    }

    #[test]
    fn a_locate_while_playing_starts_a_new_run() {
        let mut clocks: Vec<Clock> = (0..10)
            .map(|k| clock(k as f64, 100.0 + k as f64, true))
            .collect();
        clocks.extend((10..20).map(|k| clock(k as f64, 500.0 + k as f64, true)));
        let track = ShowTrack::new(&clocks);
        assert_eq!(track.show_at(3.0).unwrap().0, 103.0);
        assert_eq!(track.show_at(15.0).unwrap().0, 515.0);
        assert_eq!(track.show_at(30.0).unwrap().0, 530.0);
    }

    #[test]
    fn a_parked_clock_gives_no_show_time() {
        let track = ShowTrack::new(&[clock(0.5, 10.0, false), clock(2.0, 10.0, false)]);
        assert!(track.is_empty());
        assert_eq!(track.show_at(0.0), None);
    }
}
