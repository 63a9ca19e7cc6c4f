//! The supervisor on the one service loop ([`pipeline::service_loop`]):
//! what the services announce, Tracks, masks and frames arrive as events;
//! each tick routes, watches the services (deaths, stalls) and ends the run
//! when every frame is recorded.

use std::time::{Duration, Instant};

use anyhow::Result;
use pipeline::progress::Progress;
use pipeline::service_loop::{self, Drain, Event, Flow};
use pipeline::transport::{
    attach, cleanup_dead_nodes, waitset, Receiver, Sample, Sender, Svc, Transport,
};
use run_folder::mask_record::MaskRecorder;
use shared_types::names::Topic;
use shared_types::{Control, FrameHeader, Lifecycle, MasksHeader, Route, ServiceKind, Track};

use super::Supervisor;

pub(super) type MasksSample = Sample<Svc, [u8], MasksHeader>;
type FrameSample = Sample<Svc, [u8], FrameHeader>;

/// The event loop; returns true when interrupted by SIGINT/SIGTERM.
pub(super) fn supervise(sup: &mut Supervisor) -> Result<bool> {
    let transport = Transport::open(&sup.names, "supervisor")?;
    if sup.config.run.private {
        // The supervisor's node made the run's management file; the services
        // create theirs under the inherited umask.
        let changed = pipeline::transport::make_run_files_private(&sup.names)?;
        tracing::debug!(changed, "run's shared memory made owner-only");
    }
    let frames = transport.slice_receiver::<FrameHeader>(Topic::Frames)?;
    let tracks = transport.receiver::<Track>(Topic::Tracks)?;
    let masks = transport.slice_receiver::<MasksHeader>(Topic::Masks)?;
    // The source's frames, listed once: the progress bar's length and the
    // timestamps the ground-truth masks are looked up by.
    let listed = sup.config.source.recorded_frames().ok();
    let expected = listed.as_ref().map_or(0, |f| f.len() as u64);
    let truth = match (
        datasets::source::MaskList::open(&sup.config.source.path),
        listed,
    ) {
        (Ok(Some(masks)), Some(frames)) => Some(run_folder::mask_record::Truth {
            masks,
            timestamps: frames.iter().map(|f| f.timestamp).collect(),
            ignore: run_folder::ignore::IgnoreRegions::open(&sup.config.source.path)?,
        }),
        _ => None,
    };
    let recorder = MaskRecorder::start(&sup.run_dir, sup.config.run.save_masks, truth)?;
    let lifecycle = transport.receiver::<Lifecycle>(Topic::Lifecycle)?;
    let routes = transport.sender::<Route>(Topic::Routes)?;
    let control = transport.sender::<Control>(Topic::Control)?;
    let ws = waitset()?;
    let _a = attach(&ws, &frames)?;
    let _b = attach(&ws, &tracks)?;
    let _c = attach(&ws, &lifecycle)?;
    let _d = attach(&ws, &masks)?;
    let period = Duration::from_millis(sup.config.supervisor.watch_period_ms);

    let kinds: Vec<ServiceKind> = sup
        .services
        .iter()
        .map(|s| s.kind)
        .filter(|k| *k != ServiceKind::CameraReader)
        .collect();
    for kind in kinds {
        sup.start(kind);
    }
    let mut watch = Watch {
        sup,
        ports: Ports {
            lifecycle: &lifecycle,
            tracks: &tracks,
            masks: &masks,
            frames: &frames,
            routes: &routes,
            control: &control,
        },
        recorder,
        // A progress bar over the frames the source will play (known up
        // front from its lists; the reader announces the exact end of the
        // stream).
        progress: Progress::new("frames", expected),
        expected,
        shown: 0,
        last_sweep: Instant::now(),
        period,
        interrupted: false,
        drain: Drain::default(),
    };
    service_loop::run(&ws, &mut watch)?;
    let Watch {
        sup,
        recorder,
        mut progress,
        interrupted,
        ..
    } = watch;
    progress.finish();
    sup.stop_all();
    sup.watch_children(true)?;
    let skipped = recorder.finish()?;
    if skipped > 0 {
        tracing::warn!("{skipped} sets of masks were not recorded (the writer fell behind)");
    }
    Ok(interrupted)
}

/// What arrives for the supervisor, in the order a wake-up drains it.
enum Arrival {
    /// A service announced it is up.
    Ready(Lifecycle),
    /// The wake-up's announcements are read: the source may start now.
    ServicesSettled,
    Track(Track),
    Masks(MasksSample),
    Frame(FrameSample),
}

/// The supervisor's ports.
struct Ports<'a> {
    lifecycle: &'a Receiver<Lifecycle, ()>,
    tracks: &'a Receiver<Track, ()>,
    masks: &'a Receiver<[u8], MasksHeader>,
    frames: &'a Receiver<[u8], FrameHeader>,
    routes: &'a Sender<Route, ()>,
    control: &'a Sender<Control, ()>,
}

/// The supervisor as the service loop drives it.
struct Watch<'a> {
    sup: &'a mut Supervisor,
    ports: Ports<'a>,
    recorder: MaskRecorder,
    progress: Progress,
    /// Frames the source will play (0: not known), and how many the
    /// progress bar shows.
    expected: u64,
    shown: u64,
    /// When dead services' iceoryx2 resources were last swept.
    last_sweep: Instant,
    period: Duration,
    interrupted: bool,
    drain: Drain,
}

impl service_loop::Service for Watch<'_> {
    type Event = Arrival;

    fn patience(&self) -> Duration {
        self.period
    }

    fn woke(&mut self) {
        self.drain.restart();
    }

    fn next_event(&mut self) -> Result<Option<Arrival>> {
        let p = &self.ports;
        self.drain.next(5, |stage, entering| {
            Ok(match stage {
                0 => p.lifecycle.entered(entering).next()?.map(Arrival::Ready),
                1 => entering.then_some(Arrival::ServicesSettled),
                2 => p.tracks.entered(entering).next()?.map(Arrival::Track),
                3 => p.masks.entered(entering).next_sample()?.map(Arrival::Masks),
                _ => p
                    .frames
                    .entered(entering)
                    .next_sample()?
                    .map(Arrival::Frame),
            })
        })
    }

    fn handle(&mut self, event: Event<Arrival>) -> Result<Flow> {
        let sup = &mut *self.sup;
        match event {
            Event::Arrived(Arrival::Ready(msg)) => sup.on_ready(msg, self.ports.control)?,
            Event::Arrived(Arrival::ServicesSettled) => sup.start_source_when_ready(),
            Event::Arrived(Arrival::Track(t)) => sup.on_track(t)?,
            Event::Arrived(Arrival::Masks(sample)) => sup.on_masks(sample, &mut self.recorder)?,
            Event::Arrived(Arrival::Frame(sample)) => {
                let header = *sample.user_header();
                let problem = match &mut sup.external {
                    Some(stream) => stream
                        .check(&header, sample.payload().len(), &sup.config)
                        .err(),
                    None => None,
                };
                drop(sample);
                sup.on_frame(&header, problem, self.ports.routes)?;
            }
            Event::Tick => return self.tick(),
            Event::Shutdown => {
                tracing::warn!("termination requested; stopping the services");
                self.interrupted = true;
            }
        }
        Ok(Flow::Continue)
    }
}

impl Watch<'_> {
    /// Routes what is ready, watches the services, ends the run when every
    /// frame is recorded (or a failure is fatal).
    fn tick(&mut self) -> Result<Flow> {
        let (sup, p) = (&mut *self.sup, &self.ports);
        sup.route_ready(p.routes)?;
        // Services only fail when one dies: what follows from it is decided then.
        sup.on_deaths(p.routes, p.control, p.tracks)?;
        sup.check_stall();
        if sup.fatal.is_some() {
            return Ok(Flow::Stop);
        }
        if self.last_sweep.elapsed() > Duration::from_secs(1) {
            cleanup_dead_nodes(&sup.names)?;
            self.last_sweep = Instant::now();
        }
        if self.expected > 0 && sup.ledger.recorded().len() != self.shown {
            self.shown = sup.ledger.recorded().len();
            self.progress.set(self.shown);
        }
        if sup.ledger.complete() {
            return Ok(Flow::Stop);
        }
        // Real time: the last frames may never be tracked; they get a moment.
        for d in sup.ledger.on_tick(Instant::now()) {
            sup.write_dropped(d)?;
        }
        if sup.status_dirty {
            sup.write_status("running", None);
        }
        Ok(Flow::Continue)
    }
}
