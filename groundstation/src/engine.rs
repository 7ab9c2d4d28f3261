//! The model on its own thread, so the UI never waits for the graph, the map or the network.
//!
//! The engine thread owns the [`TeamModel`] (and, live, talks to the [`crate::net`] thread; in
//! replay, owns the [`Replay`]). It publishes a [`TeamView`] snapshot at most every
//! [`PUBLISH_PERIOD`] (10 Hz); [`Engine::view`] hands out the latest one (an `Arc` clone under a
//! lock held only for that). Operator actions go in through a bounded channel; replay controls
//! (seek, play, speed) are handled by the engine, everything else by the model, whose refusals
//! appear in the view's notices. Dropping the engine stops and joins its threads.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TryRecvError, TrySendError, sync_channel};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::model::{ModelConfig, TeamModel};
use crate::net::{self, LinkSpec, NetError, NetHandle};
use crate::replay::{Replay, ReplayError};
use crate::view::{TeamView, UiAction};

/// Snapshots are published at most this often.
pub const PUBLISH_PERIOD: Duration = Duration::from_millis(100);
/// Operator actions waiting for the engine.
pub const ACTION_CAPACITY: usize = 64;
/// The engine's loop period when nothing arrives.
const STEP: Duration = Duration::from_millis(10);
/// The model clones its protocol endpoint (~400 KB) for replay checkpoints.
const ENGINE_STACK_BYTES: usize = 16 << 20;
/// Replay speeds accepted, × real time.
pub const REPLAY_SPEEDS: std::ops::RangeInclusive<f64> = 0.1..=100.0;

#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    #[error("network: {0}")]
    Net(#[from] NetError),
    #[error("replay: {0}")]
    Replay(#[from] ReplayError),
    #[error("the engine is busy: {ACTION_CAPACITY} actions are already waiting")]
    Busy,
    #[error("the engine has stopped")]
    Stopped,
    #[error("starting the engine thread: {0}")]
    Thread(std::io::Error),
}

/// See the module documentation.
#[derive(Debug)]
pub struct Engine {
    actions: SyncSender<UiAction>,
    published: Arc<Mutex<Arc<TeamView>>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    local_addr: Option<std::net::SocketAddr>,
}

impl Engine {
    /// Opens the link and runs the model on it.
    pub fn live(spec: LinkSpec, config: ModelConfig) -> Result<Engine, EngineError> {
        let epoch = Instant::now();
        let net = net::spawn(&spec, epoch)?;
        let local_addr = net.local_addr();
        let model = TeamModel::new(config);
        let mut engine = Engine::start(model.view().clone(), move |ctx| run_live(ctx, model, net, epoch))?;
        engine.local_addr = local_addr;
        Ok(engine)
    }

    /// Opens a recorded mission directory and plays it from its start at real time.
    pub fn replay(dir: &Path, config: ModelConfig) -> Result<Engine, EngineError> {
        let mut replay = Replay::open(dir, config)?;
        replay.publish_state(true, 1.0);
        let first = replay.model().view().clone();
        Engine::start(first, move |ctx| run_replay(ctx, replay))
    }

    fn start(first: TeamView, run: impl FnOnce(Context) + Send + 'static) -> Result<Engine, EngineError> {
        let (actions, action_rx) = sync_channel(ACTION_CAPACITY);
        let published = Arc::new(Mutex::new(Arc::new(first)));
        let stop = Arc::new(AtomicBool::new(false));
        let ctx = Context { actions: action_rx, published: Arc::clone(&published), stop: Arc::clone(&stop) };
        let thread = std::thread::Builder::new()
            .name("gs-engine".into())
            .stack_size(ENGINE_STACK_BYTES)
            .spawn(move || run(ctx))
            .map_err(EngineError::Thread)?;
        Ok(Engine { actions, published, stop, thread: Some(thread), local_addr: None })
    }

    /// The latest published snapshot.
    pub fn view(&self) -> Arc<TeamView> {
        Arc::clone(&self.published.lock().unwrap_or_else(PoisonError::into_inner))
    }

    /// Queues an operator action without waiting.
    pub fn act(&self, action: UiAction) -> Result<(), EngineError> {
        self.actions.try_send(action).map_err(|e| match e {
            TrySendError::Full(_) => EngineError::Busy,
            TrySendError::Disconnected(_) => EngineError::Stopped,
        })
    }

    /// The bound UDP address of a live engine (the port the OS chose for port 0).
    pub fn local_addr(&self) -> Option<std::net::SocketAddr> {
        self.local_addr
    }
}

impl Drop for Engine {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

struct Context {
    actions: Receiver<UiAction>,
    published: Arc<Mutex<Arc<TeamView>>>,
    stop: Arc<AtomicBool>,
}

impl Context {
    fn publish(&self, view: &TeamView) {
        let snapshot = Arc::new(view.clone());
        *self.published.lock().unwrap_or_else(PoisonError::into_inner) = snapshot;
    }

    fn stopped(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }
}

fn elapsed_ns(epoch: Instant) -> u64 {
    u64::try_from(epoch.elapsed().as_nanos()).unwrap_or(u64::MAX)
}

fn run_live(ctx: Context, mut model: TeamModel, net: NetHandle, epoch: Instant) {
    let mut last_publish = Instant::now();
    while !ctx.stopped() {
        match net.incoming.recv_timeout(STEP) {
            Ok(first) => {
                model.ingest(first.recv_ns, &first.packet);
                // Bounded: at most one channel's worth per step, so actions and ticks keep going.
                for incoming in net.incoming.try_iter().take(net::INCOMING_CAPACITY) {
                    model.ingest(incoming.recv_ns, &incoming.packet);
                }
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        let now_ns = elapsed_ns(epoch);
        loop {
            match ctx.actions.try_recv() {
                // Refusals are in the model's notices.
                Ok(action) => {
                    let _ = model.apply(now_ns, &action);
                }
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => return,
            }
        }
        model.tick(now_ns);
        while let Some((robot, packet)) = model.poll_transmit(now_ns) {
            // A full queue loses the packet; the endpoint retransmits what must arrive.
            let _ = net.outgoing.try_send((robot, packet));
        }
        if last_publish.elapsed() >= PUBLISH_PERIOD {
            ctx.publish(model.view());
            last_publish = Instant::now();
        }
    }
}

fn run_replay(ctx: Context, mut replay: Replay) {
    let mut playing = true;
    let mut speed = 1.0f64;
    let mut last_step = Instant::now();
    let mut last_publish = Instant::now() - PUBLISH_PERIOD;
    let mut dirty = true;
    while !ctx.stopped() {
        let action = match ctx.actions.recv_timeout(STEP) {
            Ok(action) => Some(action),
            Err(RecvTimeoutError::Timeout) => None,
            Err(RecvTimeoutError::Disconnected) => return,
        };
        if let Some(action) = action {
            dirty = true;
            match action {
                UiAction::ReplaySeek(position_ns) => replay.seek(position_ns),
                UiAction::ReplayPlay(play) => {
                    if play && replay.position_ns() >= replay.end_ns() {
                        replay.seek(replay.start_ns());
                    }
                    playing = play;
                }
                UiAction::ReplaySpeed(s) if s.is_finite() => {
                    speed = s.clamp(*REPLAY_SPEEDS.start(), *REPLAY_SPEEDS.end())
                }
                other => {
                    let now = replay.position_ns();
                    let _ = replay_model_action(&mut replay, now, &other);
                }
            }
        }
        let wall_ns = u64::try_from(last_step.elapsed().as_nanos()).unwrap_or(0);
        last_step = Instant::now();
        if playing {
            let advance = (wall_ns as f64 * speed) as u64;
            replay.seek(replay.position_ns().saturating_add(advance));
            if replay.position_ns() >= replay.end_ns() {
                playing = false;
            }
            dirty = true;
        }
        if dirty && last_publish.elapsed() >= PUBLISH_PERIOD {
            replay.publish_state(playing, speed);
            ctx.publish(replay.model().view());
            last_publish = Instant::now();
            dirty = false;
        }
    }
}

/// Non-replay actions in a replay: the reference robot can change; commands are refused (the
/// model says why in its notices).
fn replay_model_action(replay: &mut Replay, now_ns: u64, action: &UiAction) -> Result<(), crate::model::ActionError> {
    replay.apply(now_ns, action)
}
