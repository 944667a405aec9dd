//! The jobs: each command of the tool as a `Job` in and a `Report` out, above the pipeline's
//! stages (mesh → fem → assembly → eigen → shape → audio → analysis → inverse → diagnose) and
//! below the command line, which only parses, merges configuration files and prints.
//!
//! A job reports progress through a [`Progress`] callback, so the same job runs silently in a
//! test, prints timed lines on a terminal, or feeds another program.

use std::time::Instant;

/// Progress of a long job: each message goes to a callback with the seconds since the job began.
pub struct Progress {
    start: Instant,
    sink: Option<Box<dyn Fn(f64, &str)>>,
}

impl Progress {
    /// Progress that goes nowhere (tests, library use).
    pub fn silent() -> Self {
        Progress {
            start: Instant::now(),
            sink: None,
        }
    }

    /// Progress handed to `callback(seconds_since_start, message)`.
    pub fn new(callback: impl Fn(f64, &str) + 'static) -> Self {
        Progress {
            start: Instant::now(),
            sink: Some(Box::new(callback)),
        }
    }

    /// Whether anyone listens (so a job can skip composing costly messages).
    pub fn enabled(&self) -> bool {
        self.sink.is_some()
    }

    /// Reports one message.
    pub fn say(&self, msg: impl AsRef<str>) {
        if let Some(sink) = &self.sink {
            sink(self.start.elapsed().as_secs_f64(), msg.as_ref());
        }
    }
}
