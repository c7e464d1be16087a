//! DIMSE C-STORE (PS3.7 9.1.1) through dicom-rs's upper layer: one association per batch, a
//! presentation context per (SOP class, transfer syntax) of the batch's files, each file's data
//! set sent as it is on disk (no transcoding), each C-STORE-RSP status checked.

use super::destination::{Destination, Target};
use super::error::{PacsError, StoreError};
use super::instance::{status_text, Instance, Outcome, Sender, Unfinished};
use dicom_core::{dicom_value, DataElement, VR};
use dicom_dictionary_std::tags;
use dicom_object::InMemDicomObject;
use dicom_transfer_syntax_registry::entries::IMPLICIT_VR_LITTLE_ENDIAN;
use dicom_ul::pdu::{PDataValue, PDataValueType, PresentationContextResultReason};
use dicom_ul::{ClientAssociationOptions, Pdu};
use std::time::Duration;

pub struct CStoreClient {
    host: String,
    port: u16,
    called_ae: String,
    calling_ae: String,
    timeout: Duration,
    /// Longest the association, or one instance's exchange, may take.
    deadline: Duration,
}

impl CStoreClient {
    pub fn new(destination: &Destination) -> CStoreClient {
        match &destination.target {
            Target::CStore {
                host,
                port,
                called_ae,
                calling_ae,
            } => CStoreClient {
                host: host.clone(),
                port: *port,
                called_ae: called_ae.clone(),
                calling_ae: calling_ae.clone(),
                timeout: destination.timeout,
                deadline: destination.deadline,
            },
            Target::Stow { .. } => unreachable!("a C-STORE client for a STOW-RS destination"),
        }
    }

    fn peer(&self) -> String {
        format!("{}@{}:{}", self.called_ae, self.host, self.port)
    }
}

fn trim(uid: &str) -> &str {
    uid.trim_end_matches(['\0', ' '])
}

const DEFLATED_EXPLICIT_VR_LITTLE_ENDIAN: &str = "1.2.840.10008.1.2.1.99";
const EXPLICIT_VR_LITTLE_ENDIAN: &str = "1.2.840.10008.1.2.1";

/// The transfer syntax an instance travels in: a deflated data set goes inflated, as the
/// explicit VR little endian it is (bit for bit the same data set): archives built on dcmtk
/// inflate a network stream at a crawl (measured: over 20x slower, storescu -xd alike).
fn wire_syntax(instance: &Instance) -> &str {
    match trim(&instance.transfer_syntax) {
        DEFLATED_EXPLICIT_VR_LITTLE_ENDIAN => EXPLICIT_VR_LITTLE_ENDIAN,
        syntax => syntax,
    }
}

/// The data set bytes in [`wire_syntax`].
fn wire_dataset(instance: &Instance) -> Result<std::borrow::Cow<'_, [u8]>, StoreError> {
    if trim(&instance.transfer_syntax) != DEFLATED_EXPLICIT_VR_LITTLE_ENDIAN {
        return Ok(std::borrow::Cow::Borrowed(instance.dataset()));
    }
    let mut inflated = Vec::with_capacity(instance.dataset().len() * 3);
    std::io::Read::read_to_end(
        &mut flate2::read::DeflateDecoder::new(instance.dataset()),
        &mut inflated,
    )
    .map_err(StoreError::Inflate)?;
    Ok(std::borrow::Cow::Owned(inflated))
}

/// The C-STORE-RQ command set.
fn store_request(instance: &Instance, message_id: u16) -> InMemDicomObject {
    InMemDicomObject::command_from_element_iter([
        DataElement::new(
            tags::AFFECTED_SOP_CLASS_UID,
            VR::UI,
            dicom_value!(Str, instance.sop_class_uid.as_str()),
        ),
        DataElement::new(tags::COMMAND_FIELD, VR::US, dicom_value!(U16, [0x0001])),
        DataElement::new(tags::MESSAGE_ID, VR::US, dicom_value!(U16, [message_id])),
        DataElement::new(tags::PRIORITY, VR::US, dicom_value!(U16, [0x0000])),
        DataElement::new(
            tags::COMMAND_DATA_SET_TYPE,
            VR::US,
            dicom_value!(U16, [0x0000]),
        ),
        DataElement::new(
            tags::AFFECTED_SOP_INSTANCE_UID,
            VR::UI,
            dicom_value!(Str, instance.sop_instance_uid.as_str()),
        ),
    ])
}

/// The outcome a C-STORE-RSP status means (PS3.4 B.2.3): success and warnings are stored.
pub fn outcome(status: u16, comment: Option<&str>) -> Outcome {
    match status {
        0x0000 | 0x0001 | 0x0107 | 0x0116 | 0xB000..=0xBFFF => Outcome::Stored,
        _ => Outcome::Rejected(format!(
            "C-STORE status {status:04X}H ({}){}",
            status_text(status),
            comment.map(|c| format!(": {c}")).unwrap_or_default()
        )),
    }
}

impl Sender for CStoreClient {
    fn send(&mut self, batch: &[Instance], deadline: Duration) -> Result<Vec<Outcome>, Unfinished> {
        // The exchange runs on a runtime of its own, from this thread, so that a deadline can end
        // it wherever it waits: dropping the association's future closes its socket (a blocking
        // read cannot be ended, and an archive trickling one byte at a time never lets a read
        // timeout fire).
        // (Multi-threaded, one worker: dicom-ul's P-DATA writer flushes on drop through
        // `block_in_place`, which a current-thread runtime refuses.)
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name(format!("pacs-cstore-{}", self.called_ae))
            .enable_io()
            .enable_time()
            .build()
            .map_err(|source| PacsError::Thread {
                destination: self.peer(),
                source,
            })?;
        runtime.block_on(self.send_within(batch, deadline))
    }
}

impl CStoreClient {
    /// The batch on one association: at most `self.deadline` to associate and per instance,
    /// `deadline` in all.
    async fn send_within(
        &self,
        batch: &[Instance],
        deadline: Duration,
    ) -> Result<Vec<Outcome>, Unfinished> {
        use tokio::time::{timeout_at, Instant};
        let peer = self.peer();
        let end = Instant::now() + deadline;
        let step_end = || (Instant::now() + self.deadline).min(end);
        let late = |until: Instant| PacsError::Deadline {
            peer: format!("C-STORE to {peer}"),
            seconds: if until == end {
                deadline.as_secs_f64()
            } else {
                self.deadline.as_secs_f64()
            },
        };
        let mut contexts: Vec<(&str, &str)> = batch
            .iter()
            .map(|i| (trim(&i.sop_class_uid), wire_syntax(i)))
            .collect();
        contexts.sort();
        contexts.dedup();
        let mut options = ClientAssociationOptions::new()
            .calling_ae_title(self.calling_ae.as_str())
            .called_ae_title(self.called_ae.as_str())
            .connection_timeout(self.timeout)
            .read_timeout(self.timeout)
            .write_timeout(self.timeout);
        for (class, syntax) in &contexts {
            options = options.with_presentation_context(*class, vec![*syntax]);
        }
        let address = format!("{}:{}", self.host, self.port);
        let until = step_end();
        let mut association =
            match timeout_at(until, options.establish_async(address.as_str())).await {
                Ok(Ok(association)) => association,
                Ok(Err(source)) => {
                    return Err(PacsError::Association {
                        peer: peer.clone(),
                        source: Box::new(source),
                    }
                    .into())
                }
                Err(_) => return Err(late(until).into()),
            };
        // Many small PDUs per instance: without this, each waits for the peer's delayed ACK.
        let _ = association.inner_stream().set_nodelay(true);
        let accepted: Vec<_> = association
            .presentation_contexts()
            .iter()
            .filter(|pc| pc.reason == PresentationContextResultReason::Acceptance)
            .map(|pc| {
                (
                    pc.id,
                    trim(&pc.abstract_syntax).to_string(),
                    trim(&pc.transfer_syntax).to_string(),
                )
            })
            .collect();
        let mut outcomes = Vec::with_capacity(batch.len());
        let unfinished = |outcomes: Vec<Outcome>, error| Unfinished {
            answered: outcomes.into_iter().enumerate().collect(),
            error,
        };
        for (message_id, instance) in (1u16..).zip(batch) {
            let context = accepted.iter().find(|(_, class, syntax)| {
                class == trim(&instance.sop_class_uid) && syntax == wire_syntax(instance)
            });
            let Some((id, _, _)) = context else {
                outcomes.push(Outcome::Rejected(format!(
                    "{peer} accepts no presentation context for SOP class {} in transfer syntax {}",
                    instance.sop_class_uid,
                    wire_syntax(instance)
                )));
                continue;
            };
            let until = step_end();
            match timeout_at(
                until,
                store_one(&mut association, *id, instance, message_id),
            )
            .await
            {
                Ok(Ok(outcome)) => outcomes.push(outcome),
                Ok(Err(source)) => {
                    let _ = timeout_at(step_end(), association.abort()).await;
                    let error = PacsError::Store {
                        peer,
                        file: instance.file.clone(),
                        source,
                    };
                    return Err(unfinished(outcomes, error));
                }
                // Dropping the association closes the connection.
                Err(_) => return Err(unfinished(outcomes, late(until))),
            }
        }
        let until = step_end();
        match timeout_at(until, association.release()).await {
            Ok(Ok(())) => Ok(outcomes),
            Ok(Err(source)) => Err(unfinished(
                outcomes,
                PacsError::Release {
                    peer,
                    source: Box::new(source),
                },
            )),
            Err(_) => Err(unfinished(outcomes, late(until))),
        }
    }
}

/// Sends one instance on an open association and reads its C-STORE-RSP.
async fn store_one(
    association: &mut dicom_ul::association::client::AsyncClientAssociation<tokio::net::TcpStream>,
    context: u8,
    instance: &Instance,
    message_id: u16,
) -> Result<Outcome, StoreError> {
    use tokio::io::AsyncWriteExt;
    let mut command = Vec::with_capacity(160);
    store_request(instance, message_id)
        .write_dataset_with_ts(&mut command, &IMPLICIT_VR_LITTLE_ENDIAN.erased())
        .map_err(|e| StoreError::Encode(Box::new(e)))?;
    association
        .send(&Pdu::PData {
            data: vec![PDataValue {
                presentation_context_id: context,
                value_type: PDataValueType::Command,
                is_last: true,
                data: command,
            }],
        })
        .await
        .map_err(|e| StoreError::Command(Box::new(e)))?;
    {
        let dataset = wire_dataset(instance)?;
        let mut writer = association.send_pdata(context);
        writer.write_all(&dataset).await.map_err(StoreError::Data)?;
        writer.finish().await.map_err(StoreError::Data)?;
    }
    let mut response = Vec::new();
    loop {
        match association
            .receive()
            .await
            .map_err(|e| StoreError::Receive(Box::new(e)))?
        {
            Pdu::PData { data } => {
                let mut last = false;
                for value in data {
                    if value.value_type == PDataValueType::Command {
                        last |= value.is_last;
                        response.extend_from_slice(&value.data);
                    }
                }
                if last {
                    break;
                }
            }
            Pdu::AbortRQ { source } => return Err(StoreError::Aborted(format!("{source:?}"))),
            pdu => return Err(StoreError::Unexpected(pdu.short_description().to_string())),
        }
    }
    let response = InMemDicomObject::read_dataset_with_ts(
        response.as_slice(),
        &IMPLICIT_VR_LITTLE_ENDIAN.erased(),
    )
    .map_err(|e| StoreError::Response(Box::new(e)))?;
    let status = response
        .element(tags::STATUS)
        .ok()
        .and_then(|e| e.to_int::<u16>().ok())
        .ok_or(StoreError::NoStatus)?;
    let comment = response
        .element(tags::ERROR_COMMENT)
        .ok()
        .and_then(|e| e.to_str().ok())
        .map(|c| crate::logging::escape(c.trim()));
    Ok(outcome(status, comment.as_deref()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    #[test]
    fn statuses_map_to_stored_or_rejected_with_reason() {
        assert_eq!(outcome(0x0000, None), Outcome::Stored);
        assert_eq!(outcome(0xB007, None), Outcome::Stored);
        assert_eq!(
            outcome(0xA900, Some("bad")),
            Outcome::Rejected(
                "C-STORE status A900H (error: data set does not match SOP class): bad".into()
            )
        );
        assert!(
            matches!(outcome(0xC000, None), Outcome::Rejected(r) if r.contains("cannot understand"))
        );
    }

    #[test]
    fn a_deflated_data_set_travels_inflated_as_explicit_little_endian() {
        let dataset: Vec<u8> = (0..999u32).flat_map(|i| (i % 7).to_le_bytes()).collect();
        let mut encoder =
            flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::default());
        encoder.write_all(&dataset).unwrap();
        let mut bytes = vec![0u8; 132];
        bytes.extend(encoder.finish().unwrap());
        let instance = Instance {
            file: "L00001.dcm".into(),
            sop_class_uid: "1.2.840.10008.5.1.4.1.1.2".into(),
            sop_instance_uid: "1.2.3".into(),
            transfer_syntax: format!("{DEFLATED_EXPLICIT_VR_LITTLE_ENDIAN}\0"),
            bytes,
            dataset_offset: 132,
        };
        assert_eq!(wire_syntax(&instance), EXPLICIT_VR_LITTLE_ENDIAN);
        assert_eq!(
            wire_dataset(&instance).unwrap().as_ref(),
            dataset.as_slice()
        );
    }
}
