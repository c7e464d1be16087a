//! DICOMweb STOW-RS (PS3.18 10.5): one `multipart/related; type="application/dicom"` POST to
//! `{url}/studies` per batch; the answer's ReferencedSOPSequence (0008,1199) lists what the
//! archive stored, its FailedSOPSequence (0008,1198) what it refused, with FailureReason
//! (0008,1197).

use super::destination::{Destination, Target};
use super::error::{PacsError, TransportError, Unmentioned};
use super::instance::{status_text, Instance, Outcome, Sender, Unfinished};
use serde_json::Value;
use std::collections::HashMap;
use std::time::Duration;

pub struct StowClient {
    agent: ureq::Agent,
    url: String,
    authorization: Option<String>,
}

impl StowClient {
    pub fn new(destination: &Destination) -> StowClient {
        let (url, authorization) = match &destination.target {
            Target::Stow { url, authorization } => (url.clone(), authorization.clone()),
            Target::CStore { .. } => unreachable!("a STOW-RS client for a C-STORE destination"),
        };
        let agent = ureq::AgentBuilder::new()
            .timeout_connect(destination.timeout)
            .timeout_read(destination.timeout)
            .timeout_write(destination.timeout)
            .user_agent(concat!("layerwise/", env!("CARGO_PKG_VERSION")))
            .build();
        StowClient {
            agent,
            url: format!("{url}/studies"),
            authorization,
        }
    }
}

/// The multipart body of a batch and its boundary.
pub fn multipart(batch: &[Instance]) -> (Vec<u8>, String) {
    let boundary = format!(
        "layerwise-{:016x}",
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as u64)
    );
    let total: usize = batch.iter().map(|i| i.bytes.len() + 80).sum();
    let mut body = Vec::with_capacity(total + 64);
    for instance in batch {
        body.extend_from_slice(
            format!("--{boundary}\r\nContent-Type: application/dicom\r\n\r\n").as_bytes(),
        );
        body.extend_from_slice(&instance.bytes);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
    (body, boundary)
}

impl Sender for StowClient {
    fn send(&mut self, batch: &[Instance], deadline: Duration) -> Result<Vec<Outcome>, Unfinished> {
        let (body, boundary) = multipart(batch);
        let started = std::time::Instant::now();
        // The whole exchange, connection to the answer's last byte, within the deadline: an
        // archive that trickles its answer cannot hold the push (ureq's read timeout restarts
        // with every byte).
        let mut request = self
            .agent
            .post(&self.url)
            .timeout(deadline)
            .set(
                "Content-Type",
                &format!("multipart/related; type=\"application/dicom\"; boundary={boundary}"),
            )
            .set("Accept", "application/dicom+json");
        if let Some(authorization) = &self.authorization {
            request = request.set("Authorization", authorization);
        }
        let url = || self.url.clone();
        let (status, text) = match request.send_bytes(&body) {
            Ok(response) => {
                let status = response.status();
                let text = response.into_string();
                if text.is_err() && started.elapsed() >= deadline {
                    return Err(PacsError::Deadline {
                        peer: format!("POST {}", url()),
                        seconds: deadline.as_secs_f64(),
                    }
                    .into());
                }
                (status, text.unwrap_or_default())
            }
            // 409 (all failed) and other statuses may still carry the per-instance answer.
            Err(ureq::Error::Status(status, response)) => {
                let text = response.into_string().unwrap_or_default();
                match status {
                    401 | 403 => return Err(PacsError::Unauthorized { url: url(), status }.into()),
                    400 | 409 | 415 if parse_json(&text).is_ok() => (status, text),
                    _ => {
                        return Err(PacsError::Http {
                            url: url(),
                            status,
                            body: short(&text),
                        }
                        .into())
                    }
                }
            }
            Err(ureq::Error::Transport(_)) if started.elapsed() >= deadline => {
                return Err(PacsError::Deadline {
                    peer: format!("POST {}", url()),
                    seconds: deadline.as_secs_f64(),
                }
                .into());
            }
            Err(ureq::Error::Transport(e)) => {
                return Err(PacsError::Connect {
                    url: url(),
                    source: TransportError(Box::new(e)),
                }
                .into());
            }
        };
        let answer = parse_json(&text).map_err(|source| PacsError::NotStow {
            url: url(),
            status,
            body: short(&text),
            source,
        })?;
        let outcomes = outcomes(batch, &answer);
        let missing: Vec<usize> = (0..batch.len())
            .filter(|&i| outcomes[i].is_none())
            .collect();
        let Some(&first) = missing.first() else {
            return Ok(outcomes.into_iter().flatten().collect());
        };
        // What the archive answered for is logged; the rest is sent again.
        Err(Unfinished {
            answered: outcomes
                .into_iter()
                .enumerate()
                .filter_map(|(i, o)| Some((i, o?)))
                .collect(),
            error: PacsError::Answer {
                url: url(),
                source: Unmentioned {
                    uid: batch[first].sop_instance_uid.clone(),
                    file: batch[first].file.clone(),
                    missing: missing.len(),
                    total: batch.len(),
                },
            },
        })
    }
}

/// The answer as a DICOM JSON object; not JSON (the parser's error), or JSON but not an object.
fn parse_json(text: &str) -> Result<Value, Option<serde_json::Error>> {
    match serde_json::from_str::<Value>(text) {
        Ok(value) if value.is_object() => Ok(value),
        Ok(_) => Err(None),
        Err(e) => Err(Some(e)),
    }
}

/// The first line of a body, shortened and escaped (an archive's text never acts on the
/// operator's terminal), for an error message.
fn short(text: &str) -> Option<String> {
    let line = text.lines().map(str::trim).find(|l| !l.is_empty())?;
    Some(crate::logging::escape(
        &line.chars().take(200).collect::<String>(),
    ))
}

/// The items of a sequence attribute in DICOM JSON.
fn items<'a>(answer: &'a Value, tag: &str) -> impl Iterator<Item = &'a Value> {
    answer
        .get(tag)
        .and_then(|a| a.get("Value"))
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
}

fn first_value<'a>(item: &'a Value, tag: &str) -> Option<&'a Value> {
    item.get(tag)?.get("Value")?.as_array()?.first()
}

/// Each instance's outcome from the STOW-RS answer, `None` for an instance the answer does not
/// mention (its fate is unknown: it is sent again later).
pub fn outcomes(batch: &[Instance], answer: &Value) -> Vec<Option<Outcome>> {
    let mut by_uid: HashMap<String, Outcome> = HashMap::new();
    for item in items(answer, "00081199") {
        if let Some(uid) = first_value(item, "00081155").and_then(Value::as_str) {
            by_uid.insert(uid.to_string(), Outcome::Stored);
        }
    }
    for item in items(answer, "00081198") {
        let Some(uid) = first_value(item, "00081155").and_then(Value::as_str) else {
            continue;
        };
        let reason = match first_value(item, "00081197").and_then(Value::as_u64) {
            Some(code) => format!(
                "STOW-RS FailureReason {code:04X}H ({})",
                status_text(code as u16)
            ),
            None => "in FailedSOPSequence without a FailureReason".to_string(),
        };
        by_uid.insert(uid.to_string(), Outcome::Rejected(reason));
    }
    batch
        .iter()
        .map(|instance| by_uid.get(&instance.sop_instance_uid).cloned())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn instance(uid: &str) -> Instance {
        Instance {
            file: format!("{uid}.dcm"),
            sop_class_uid: "1.2.840.10008.5.1.4.1.1.7".into(),
            sop_instance_uid: uid.into(),
            transfer_syntax: "1.2.840.10008.1.2.1".into(),
            bytes: vec![7; 140],
            dataset_offset: 132,
        }
    }

    #[test]
    fn the_answer_says_stored_or_rejected_with_reason_per_instance() {
        let answer: Value = serde_json::from_str(
            r#"{"00081199":{"vr":"SQ","Value":[{"00081155":{"vr":"UI","Value":["1.1"]}}]},
                "00081198":{"vr":"SQ","Value":[{"00081155":{"vr":"UI","Value":["1.2"]},
                                                "00081197":{"vr":"US","Value":[272]}}]}}"#,
        )
        .unwrap();
        let batch = [instance("1.1"), instance("1.2")];
        let got = outcomes(&batch, &answer);
        assert_eq!(got[0], Some(Outcome::Stored));
        assert_eq!(
            got[1],
            Some(Outcome::Rejected(
                "STOW-RS FailureReason 0110H (processing failure)".into()
            ))
        );
        assert_eq!(outcomes(&[instance("1.3")], &answer), [None]);
    }

    #[test]
    fn the_body_is_multipart_related_with_every_file_whole() {
        let batch = [instance("1.1"), instance("1.2")];
        let (body, boundary) = multipart(&batch);
        let text = String::from_utf8_lossy(&body);
        assert_eq!(text.matches(&format!("--{boundary}\r\n")).count(), 2);
        assert!(text.ends_with(&format!("--{boundary}--\r\n")));
        assert_eq!(body.iter().filter(|&&b| b == 7).count(), 280);
    }
}
