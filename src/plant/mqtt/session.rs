//! The MQTT connection: queued messages sent one at a time, in order, each removed from the
//! queue once the broker acknowledged it (QoS 1); the retained `status` published on every
//! connection and on change (at most once a second); the last will (`status` offline, retained)
//! left with the broker at each connection, so a daemon killed or cut off is shown offline.
//!
//! Each connection attempt gets a new rumqttc client and event loop (the event loop polled on a
//! task of its own, never cancelled half way): nothing of a broken connection is sent on the
//! next one. The queue is fed from the daemon's events all the while, connected or not.

use super::message::Messages;
use super::outbox::Outbox;
use crate::config::mqtt::{MqttBroker, MqttConfig};
use crate::plant::event::PlantEvent;
use crate::plant::metrics::LiveMetrics;
use crate::plant::sink::PlantFeed;
use crate::shutdown::Shutdown;
use rumqttc::{
    AsyncClient, ConnectionError, Event, EventLoop, LastWill, MqttOptions, NetworkOptions,
    Outgoing, Packet, QoS, Transport,
};
use std::collections::{HashMap, VecDeque};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio::time::Instant;
use tracing::{error, info, warn};

/// How long the stop waits for the queue to empty before it disconnects.
pub const STOP_GRACE: Duration = Duration::from_secs(5);
/// The retained status is published at most this often.
const STATUS_PERIOD: Duration = Duration::from_secs(1);
/// A connection up this long counts as working (the back-off starts again after it).
const HELD: Duration = Duration::from_secs(10);
/// Largest packet accepted from the broker (we subscribe to nothing: anything bigger is a
/// broken or hostile broker, and the connection is dropped).
const MAX_INCOMING: usize = 64 << 10;
/// Largest packet sent.
const MAX_OUTGOING: usize = 256 << 10;

/// Who the daemon is to the broker.
pub struct Identity {
    pub broker: MqttBroker,
    pub client_id: String,
    pub credentials: Option<(String, String)>,
    pub tls: Option<Arc<rustls::ClientConfig>>,
}

pub struct Session {
    pub config: MqttConfig,
    pub identity: Identity,
    pub outbox: Outbox,
    pub messages: Messages,
    pub feed: PlantFeed,
    pub live: Option<Arc<LiveMetrics>>,
    pub shutdown: Shutdown,
}

/// What was handed to the client, waiting for its packet id.
#[derive(Clone, Copy, Debug)]
enum Sent {
    Status,
    Queued(u64),
}

/// How a connection ended.
enum Ended {
    /// The stop came (and was handled).
    Stop,
    /// The build's topic prefix changed: connect again at once with the new last will.
    Prefix,
    /// The connection failed or was lost: connect again after the back-off.
    Lost,
}

fn offline(reason: &str) -> String {
    serde_json::json!({ "online": false, "reason": reason, "at": chrono::Utc::now() }).to_string()
}

impl Session {
    fn options(&self, prefix: &str) -> MqttOptions {
        let id = &self.identity;
        let mut options = MqttOptions::new(&id.client_id, &id.broker.host, id.broker.port);
        options
            .set_keep_alive(Duration::from_secs(self.config.keep_alive_s))
            .set_clean_session(true)
            .set_max_packet_size(MAX_INCOMING, MAX_OUTGOING)
            .set_inflight(4)
            .set_request_channel_capacity(16)
            .set_last_will(LastWill::new(
                format!("{prefix}/status"),
                offline("lost"),
                QoS::AtLeastOnce,
                true,
            ));
        if let Some((user, password)) = &id.credentials {
            options.set_credentials(user, password);
        }
        if let Some(tls) = &id.tls {
            options.set_transport(Transport::tls_with_config(
                rumqttc::TlsConfiguration::Rustls(tls.clone()),
            ));
        }
        options
    }

    /// Connects, publishes, reconnects, until the stop.
    pub async fn run(mut self) {
        let [first, longest] = self.config.retry_backoff_ms.map(Duration::from_millis);
        let mut backoff = first;
        let mut retry_at: Option<Instant> = None;
        let mut failures = 0u64;
        loop {
            if let Some(at) = retry_at.take() {
                if self.idle_until(at).await {
                    return self.finish();
                }
            }
            let prefix = self.messages.prefix();
            let (client, eventloop) = AsyncClient::new(self.options(&prefix), 16);
            let (events, mut polled) = mpsc::channel(64);
            let poller = tokio::spawn(poll(eventloop, events));
            let ended = self.connection(&client, &mut polled, &prefix).await;
            poller.abort();
            self.gauge_connected(false);
            match ended {
                (Ended::Stop, _) => return self.finish(),
                (Ended::Prefix, _) => {}
                (Ended::Lost, up) => {
                    // A connection that held a while starts the back-off again; a broker that
                    // accepts and then fails at once is retried ever more slowly.
                    if up.is_some_and(|d| d >= HELD) {
                        backoff = first;
                        failures = 0;
                    }
                    failures += 1;
                    retry_at = Some(Instant::now() + backoff);
                    if failures == 1 || failures.is_power_of_two() {
                        warn!(
                            broker = %format!("{}:{}", self.identity.broker.host, self.identity.broker.port),
                            attempts = failures,
                            retry_in_ms = backoff.as_millis() as u64,
                            "MQTT broker unreachable; messages wait in the queue (mqtt.queue_dir)"
                        );
                    }
                    backoff = (backoff * 2).min(longest);
                }
            }
        }
    }

    /// Queues events while waiting for `at`; true when the stop came meanwhile.
    async fn idle_until(&mut self, at: Instant) -> bool {
        loop {
            tokio::select! {
                _ = tokio::time::sleep_until(at) => return false,
                _ = self.shutdown.requested() => return true,
                event = self.feed.events.recv() => match event {
                    Some(event) => self.queue(&event),
                    None => return true,
                },
            }
        }
    }

    fn queue(&mut self, event: &PlantEvent) {
        if let Err(e) = self.messages.handle(event, &mut self.outbox) {
            error!(error = %crate::logging::Chain(&e), "MQTT: cannot queue a message; it is lost");
        }
        self.gauges();
    }

    /// Whatever is still in the channel is queued; the cursor is written.
    fn finish(&mut self) {
        while let Ok(event) = self.feed.events.try_recv() {
            self.queue(&event);
        }
        self.outbox.save_cursor(true);
        self.gauges();
    }

    fn gauges(&self) {
        if let Some(live) = &self.live {
            let (messages, bytes) = self.outbox.pending();
            live.mqtt.queue_messages.set(messages as i64);
            live.mqtt.queue_bytes.set(bytes as i64);
            live.mqtt
                .dropped
                .inner()
                .store(self.outbox.dropped, std::sync::atomic::Ordering::Relaxed);
        }
    }

    fn gauge_connected(&self, connected: bool) {
        if let Some(live) = &self.live {
            live.mqtt.connected.set(i64::from(connected));
        }
    }

    /// One connection, from the attempt to its end; with how long it was up.
    async fn connection(
        &mut self,
        client: &AsyncClient,
        polled: &mut mpsc::Receiver<Result<Event, ConnectionError>>,
        prefix: &str,
    ) -> (Ended, Option<Duration>) {
        let mut connected = false;
        let mut up_at: Option<Instant> = None;
        let up = |at: Option<Instant>| at.map(|t| t.elapsed());
        let mut sent: VecDeque<Sent> = VecDeque::new();
        let mut ids: HashMap<u16, Sent> = HashMap::new();
        let (mut queued_in_flight, mut status_in_flight) = (false, false);
        let mut status_dirty = true;
        let mut status_at: Option<Instant> = None;
        // Set by the stop (or a new prefix): what to say, and until when to wait for the queue.
        let mut leaving: Option<(Ended, Instant)> = None;
        let mut offline_sent = false;
        loop {
            if connected {
                if let Some((why, deadline)) = &leaving {
                    if !offline_sent {
                        let reason = match why {
                            Ended::Prefix => "build ended",
                            _ => "stopped",
                        };
                        if client
                            .try_publish(
                                format!("{prefix}/status"),
                                QoS::AtLeastOnce,
                                true,
                                offline(reason),
                            )
                            .is_ok()
                        {
                            sent.push_back(Sent::Status);
                            status_in_flight = true;
                            offline_sent = true;
                        }
                    }
                    let drained = matches!(why, Ended::Prefix) || self.outbox.pending().0 == 0;
                    if (offline_sent && !status_in_flight && drained && !queued_in_flight)
                        || Instant::now() >= *deadline
                    {
                        let _ = client.try_disconnect();
                        // The DISCONNECT is written on the next poll: wait for it briefly.
                        let _ = tokio::time::timeout(Duration::from_secs(1), async {
                            while let Some(Ok(event)) = polled.recv().await {
                                if matches!(event, Event::Outgoing(Outgoing::Disconnect)) {
                                    break;
                                }
                            }
                        })
                        .await;
                        let (why, _) = leaving.take().expect("leaving");
                        return (why, up(up_at));
                    }
                } else if status_dirty
                    && !status_in_flight
                    && status_at.is_none_or(|t| t.elapsed() >= STATUS_PERIOD)
                {
                    let payload = {
                        let status = self.feed.status.borrow_and_update();
                        self.messages.status(true, None, &status)
                    };
                    // Tried at most once a period, taken or not.
                    status_at = Some(Instant::now());
                    if client
                        .try_publish(format!("{prefix}/status"), QoS::AtLeastOnce, true, payload)
                        .is_ok()
                    {
                        sent.push_back(Sent::Status);
                        status_in_flight = true;
                        status_dirty = false;
                    }
                }
                if !queued_in_flight && !matches!(leaving, Some((Ended::Prefix, _))) {
                    match self.outbox.oldest() {
                        Ok(Some(entry)) => {
                            let seq = entry.seq;
                            let published = client.try_publish(
                                entry.topic.clone(),
                                QoS::AtLeastOnce,
                                false,
                                entry.payload.clone(),
                            );
                            if published.is_ok() {
                                sent.push_back(Sent::Queued(seq));
                                queued_in_flight = true;
                            }
                        }
                        Ok(None) => {}
                        Err(e) => {
                            error!(error = %crate::logging::Chain(&e), "MQTT: cannot read the queue");
                        }
                    }
                }
            } else if leaving.is_some() && Instant::now() >= leaving.as_ref().expect("set").1 {
                let (why, _) = leaving.take().expect("set");
                return (why, None);
            }
            // A changed status waits for the end of its period (not while one is in flight:
            // its acknowledgement wakes the loop).
            let status_wait = status_at
                .filter(|_| status_dirty && connected && !status_in_flight)
                .map(|t| t + STATUS_PERIOD);
            let deadline = leaving.as_ref().map(|(_, d)| *d);
            tokio::select! {
                _ = self.shutdown.requested(), if leaving.is_none() => {
                    while let Ok(event) = self.feed.events.try_recv() {
                        self.queue(&event);
                    }
                    if !connected {
                        return (Ended::Stop, None);
                    }
                    leaving = Some((Ended::Stop, Instant::now() + STOP_GRACE));
                }
                event = self.feed.events.recv(), if leaving.is_none() => match event {
                    Some(event) => {
                        self.queue(&event);
                        if self.messages.prefix() != prefix {
                            if !connected {
                                return (Ended::Prefix, None);
                            }
                            leaving = Some((Ended::Prefix, Instant::now() + Duration::from_secs(2)));
                        }
                    }
                    None => leaving = Some((Ended::Stop, Instant::now() + STOP_GRACE)),
                },
                changed = self.feed.status.changed(), if leaving.is_none() => {
                    if changed.is_ok() {
                        status_dirty = true;
                    }
                }
                _ = sleep_until_some(status_wait.or(deadline)) => {}
                polled = polled.recv() => match polled {
                    Some(Ok(Event::Incoming(Packet::ConnAck(_)))) => {
                        info!(broker = %format!("{}:{}", self.identity.broker.host, self.identity.broker.port), prefix, "MQTT connected");
                        connected = true;
                        up_at = Some(Instant::now());
                        status_dirty = true;
                        self.gauge_connected(true);
                    }
                    Some(Ok(Event::Outgoing(Outgoing::Publish(id)))) => {
                        if let Some(what) = sent.pop_front() {
                            ids.insert(id, what);
                        }
                    }
                    Some(Ok(Event::Incoming(Packet::PubAck(ack)))) => match ids.remove(&ack.pkid) {
                        Some(Sent::Queued(seq)) => {
                            self.outbox.ack(seq);
                            self.outbox.save_cursor(false);
                            queued_in_flight = false;
                            if let Some(live) = &self.live {
                                live.mqtt.published.inc();
                            }
                            self.gauges();
                        }
                        Some(Sent::Status) => status_in_flight = false,
                        None => {}
                    },
                    Some(Ok(_)) => {}
                    Some(Err(e)) => {
                        if connected {
                            warn!(error = %e, "MQTT connection lost; messages wait in the queue");
                        } else {
                            tracing::debug!(error = %e, "MQTT: cannot connect");
                        }
                        if let Some((why, _)) = leaving.take() {
                            return (why, up(up_at));
                        }
                        return (Ended::Lost, up(up_at));
                    }
                    None => return (Ended::Lost, up(up_at)),
                },
            }
        }
    }
}

/// Sleeps until `at`, or for ever when there is none.
async fn sleep_until_some(at: Option<Instant>) {
    match at {
        Some(at) => tokio::time::sleep_until(at).await,
        None => std::future::pending().await,
    }
}

/// Polls the event loop, handing every event over, until the connection fails (the error is the
/// last thing handed over) or nobody listens.
async fn poll(mut eventloop: EventLoop, events: mpsc::Sender<Result<Event, ConnectionError>>) {
    let mut network = NetworkOptions::new();
    network.set_connection_timeout(5);
    eventloop.set_network_options(network);
    loop {
        let event = eventloop.poll().await;
        let failed = event.is_err();
        if events.send(event).await.is_err() || failed {
            return;
        }
    }
}
