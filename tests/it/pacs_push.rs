//! Issue 30, "PACS push": archives that misbehave on purpose, served by the test on loopback
//! (a STOW-RS endpoint and a DIMSE port that trickle one byte at a time, one that confirms part
//! of a batch, one that checks the credentials of a `--to` URL), and `layerwise push` run as a
//! user runs it: an overall deadline per instance and per push that names the slow destination,
//! what an archive confirmed logged and not sent again, no credentials on disk.

use crate::common::{demo_config, layerwise, report, write_config};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// `n` DICOM slices in `dir/export` (an export folder, as `push --build` takes one); their SOP
/// Instance UIDs in file order.
fn instances(dir: &Path, n: u32) -> (PathBuf, Vec<String>) {
    let folder = dir.join("export");
    std::fs::create_dir_all(&folder).unwrap();
    let study = layerwise::dicom::Study {
        study_instance_uid: layerwise::dicom::new_uid(),
        frame_of_reference_uid: layerwise::dicom::new_uid(),
        date: "20261202".into(),
        time: "040000".into(),
        patient_name: "push^".into(),
        patient_id: "push".into(),
        study_id: "1".into(),
        description: "push".into(),
    };
    let series = layerwise::dicom::Series::named(&study, 1, "post_top");
    let pixels = vec![7u16; 16];
    let mut uids = Vec::new();
    for layer in 1..=n {
        let slice = layerwise::dicom::Slice {
            layer,
            plane: layerwise::dicom::Plane {
                origin: [0.0, 0.0, layer as f64],
                pixel_mm: 1.0,
                rows: 4,
                columns: 4,
                thickness_mm: 1.0,
            },
            pixels: layerwise::dicom::Samples::Gray16(&pixels),
            acquired: None,
            window: (0.0, 1.0),
            derivation: "test",
        };
        let path = folder.join(format!("L{layer:05}.dcm"));
        layerwise::dicom::write_slice(
            &path,
            &study,
            &series,
            &slice,
            layerwise::dicom::Compression::None,
        )
        .unwrap();
        uids.push(layerwise::dicom::file_instance_uid(&path).unwrap());
    }
    (folder, uids)
}

/// One HTTP/1.1 request read off a connection: its head (lower-case) and body.
fn read_request(reader: &mut BufReader<TcpStream>) -> Option<(String, Vec<u8>)> {
    let mut head = String::new();
    loop {
        let mut line = String::new();
        if reader.read_line(&mut line).ok()? == 0 {
            return None;
        }
        if line == "\r\n" {
            break;
        }
        head.push_str(&line.to_ascii_lowercase());
    }
    let length: usize = head
        .lines()
        .find_map(|l| l.strip_prefix("content-length:"))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(0);
    let mut body = vec![0; length];
    reader.read_exact(&mut body).ok()?;
    Some((head, body))
}

/// A STOW-RS answer storing `uids`.
fn stow_answer(uids: &[String]) -> String {
    let items: Vec<serde_json::Value> = uids
        .iter()
        .map(|u| serde_json::json!({"00081155": {"vr": "UI", "Value": [u]}}))
        .collect();
    serde_json::json!({"00081199": {"vr": "SQ", "Value": items}}).to_string()
}

/// A fake archive on loopback: `answer` gets each request (head, body) and the connection to
/// write its answer on. Runs until the test ends (its thread is detached; the listener lives
/// in it).
fn serve(answer: impl Fn(&str, &[u8], &mut TcpStream) + Send + Sync + 'static) -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let answer = Arc::new(answer);
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            let answer = answer.clone();
            std::thread::spawn(move || {
                let mut writer = stream.try_clone().unwrap();
                let mut reader = BufReader::new(stream);
                while let Some((head, body)) = read_request(&mut reader) {
                    answer(&head, &body, &mut writer);
                }
            });
        }
    });
    port
}

/// Writes `bytes` one at a time, `every` apart, until the peer hangs up or `stop` is set.
fn trickle(stream: &mut TcpStream, bytes: &[u8], every: Duration, stop: &AtomicBool) {
    for b in bytes.iter().cycle() {
        if stop.load(Ordering::SeqCst) || stream.write_all(&[*b]).is_err() {
            return;
        }
        std::thread::sleep(every);
    }
}

/// A configuration holding one `[[pacs]]` destination (`toml` its keys), for `push --config`.
fn config_with_pacs(dir: &Path, toml_text: &str) -> PathBuf {
    let mut config = demo_config(&dir.join("unused"), 2);
    config.pacs = vec![toml::from_str(toml_text).unwrap()];
    let path = dir.join("layerwise.toml");
    write_config(&config, &path);
    path
}

/// `layerwise push --build FOLDER` plus `args`, timed.
fn push(folder: &Path, args: &[&str]) -> (std::process::Output, Duration) {
    let started = Instant::now();
    let out = layerwise()
        .args(["push", "--build"])
        .arg(folder)
        .args(args)
        .output()
        .unwrap();
    (out, started.elapsed())
}

/// The finding: an archive that trickles one byte every 2 s kept one STOW-RS push busy for
/// 180 s (the 30 s read timeout restarts with each byte). With `deadline_s = 2` a batch of 3
/// instances has 6 s; with `--deadline-s 3` the push itself has 3 s. Each ends, naming the
/// destination and the deadline.
#[test]
fn stow_archive_trickling_its_answer_is_cut_at_the_deadline_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let (folder, _) = instances(dir.path(), 3);
    let stop = Arc::new(AtomicBool::new(false));
    let trickling = stop.clone();
    let port = serve(move |_, _, stream| {
        let head = "HTTP/1.1 200 OK\r\nContent-Type: application/dicom+json\r\n\
                    Content-Length: 100000\r\n\r\n";
        let _ = stream.write_all(head.as_bytes());
        trickle(stream, b"{ ", Duration::from_millis(500), &trickling);
    });
    let url = format!("http://127.0.0.1:{port}/dicom-web");
    let config = config_with_pacs(
        dir.path(),
        &format!("name = \"slowweb\"\nurl = \"{url}\"\ntimeout_s = 30\ndeadline_s = 2\n"),
    );
    let (out, took) = push(&folder, &["--config", config.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{}", report(&out));
    assert!(
        stderr.contains("slowweb") && stderr.contains("deadline of 6 s"),
        "{stderr}"
    );
    assert!(took < Duration::from_secs(20), "{took:?}");
    // The push's own deadline, for a URL given on the command line (deadline_s 60).
    let (out, took) = push(&folder, &["--to", &url, "--deadline-s", "3"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{}", report(&out));
    assert!(
        stderr.contains(&format!("127.0.0.1_{port}_dicom-web"))
            && stderr.contains("deadline of 3 s"),
        "{stderr}"
    );
    assert!(took < Duration::from_secs(15), "{took:?}");
    stop.store(true, Ordering::SeqCst);
}

/// The same for C-STORE: an archive that accepts the connection and trickles its association
/// answer one byte at a time is left at `deadline_s`, naming the destination.
#[test]
fn c_store_archive_trickling_its_association_is_cut_at_the_deadline_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let (folder, _) = instances(dir.path(), 2);
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let stop = Arc::new(AtomicBool::new(false));
    let trickling = stop.clone();
    std::thread::spawn(move || {
        for mut stream in listener.incoming().flatten() {
            let trickling = trickling.clone();
            std::thread::spawn(move || {
                // An A-ASSOCIATE-AC (type 2) that never completes.
                trickle(
                    &mut stream,
                    &[2, 0, 0, 0, 0, 0xFF],
                    Duration::from_millis(500),
                    &trickling,
                );
            });
        }
    });
    let config = config_with_pacs(
        dir.path(),
        &format!(
            "name = \"slowdimse\"\nhost = \"127.0.0.1\"\nport = {port}\ncalled_ae = \"SLOW\"\n\
             timeout_s = 30\ndeadline_s = 2\n"
        ),
    );
    let (out, took) = push(&folder, &["--config", config.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{}", report(&out));
    assert!(
        stderr.contains("slowdimse") && stderr.contains("deadline of 2 s"),
        "{stderr}"
    );
    assert!(took < Duration::from_secs(15), "{took:?}");
    stop.store(true, Ordering::SeqCst);
}

/// A DIMSE archive on loopback that accepts every association (dicom-ul's own server side),
/// takes what it is sent, and answers by trickling a P-DATA-TF one byte every second (within
/// any read timeout: only a deadline ends it). Runs until `stop` (its threads are detached).
fn trickling_store_scp(stop: Arc<AtomicBool>) -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            let stop = stop.clone();
            std::thread::spawn(move || {
                let accepted = dicom_ul::ServerAssociationOptions::new()
                    .accept_any()
                    .promiscuous(true)
                    .establish(stream);
                if let Ok(mut association) = accepted {
                    // A P-DATA-TF (type 4) of 255 bytes that never completes.
                    let stream = association.inner_stream();
                    trickle(
                        stream,
                        &[4, 0, 0, 0, 0, 0xFF],
                        Duration::from_secs(1),
                        &stop,
                    );
                }
            });
        }
    });
    port
}

/// The finding for C-STORE: an archive that accepts the association and then trickles its
/// C-STORE-RSP kept a push busy (the read timeout restarts with each byte). Each instance has
/// `deadline_s` (2 s of a 3-instance batch's 6 s), and `--deadline-s 3` bounds the push itself
/// with the destination's deadline_s at 30; each ends naming the destination and the deadline,
/// the instances left pending.
#[test]
fn c_store_archive_trickling_its_store_answer_is_cut_per_instance_and_per_push_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let (folder, _) = instances(dir.path(), 3);
    let stop = Arc::new(AtomicBool::new(false));
    let port = trickling_store_scp(stop.clone());
    let config = config_with_pacs(
        dir.path(),
        &format!(
            "name = \"slowstore\"\nhost = \"127.0.0.1\"\nport = {port}\ncalled_ae = \"SLOW\"\n\
             timeout_s = 30\ndeadline_s = 2\n"
        ),
    );
    let (out, took) = push(&folder, &["--config", config.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{}", report(&out));
    assert!(
        stderr.contains("slowstore")
            && stderr.contains(&format!("C-STORE to SLOW@127.0.0.1:{port}"))
            && stderr.contains("deadline of 2 s"),
        "{stderr}"
    );
    assert!(took < Duration::from_secs(15), "{took:?}");
    // The push's own deadline, for a destination given on the command line (deadline_s 60).
    let to = format!("dicom://SLOW@127.0.0.1:{port}");
    let (out, took) = push(&folder, &["--to", &to, "--deadline-s", "3"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{}", report(&out));
    assert!(
        stderr.contains(&format!("SLOW_127.0.0.1_{port}")) && stderr.contains("deadline of 3 s"),
        "{stderr}"
    );
    assert!(took < Duration::from_secs(15), "{took:?}");
    // Nothing was confirmed: every instance is still to push.
    for entry in std::fs::read_dir(folder.join("pacs")).into_iter().flatten() {
        let text = std::fs::read_to_string(entry.unwrap().path()).unwrap();
        assert!(!text.contains("\"kind\":\"stored\""), "{text}");
    }
    stop.store(true, Ordering::SeqCst);
}

/// The finding: an archive that confirmed 16 of a 33-instance batch got those 16 again. What it
/// confirms is logged; the next push sends only the rest.
#[test]
fn partially_confirmed_batch_logs_what_was_confirmed_and_sends_only_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let (folder, uids) = instances(dir.path(), 33);
    let received: Arc<Mutex<Vec<usize>>> = Arc::default();
    let calls = received.clone();
    let confirm_all = Arc::new(AtomicBool::new(false));
    let all = confirm_all.clone();
    let known = uids.clone();
    let port = serve(move |_, body, stream| {
        let text = String::from_utf8_lossy(body);
        let sent: Vec<String> = known
            .iter()
            .filter(|u| text.contains(u.as_str()))
            .cloned()
            .collect();
        calls.lock().unwrap().push(sent.len());
        let confirmed = if all.load(Ordering::SeqCst) {
            &sent[..]
        } else {
            &sent[..16.min(sent.len())]
        };
        let answer = stow_answer(confirmed);
        let _ = write!(
            stream,
            "HTTP/1.1 200 OK\r\nContent-Type: application/dicom+json\r\nContent-Length: {}\r\n\r\n{answer}",
            answer.len()
        );
    });
    let url = format!("http://127.0.0.1:{port}/dicom-web");
    let (out, _) = push(&folder, &["--to", &url]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{}", report(&out));
    assert!(stderr.contains("does not mention 17 of the 33"), "{stderr}");
    let log =
        std::fs::read_to_string(folder.join(format!("pacs/127.0.0.1_{port}_dicom-web.jsonl")))
            .unwrap();
    assert_eq!(log.matches("\"kind\":\"stored\"").count(), 16, "{log}");
    confirm_all.store(true, Ordering::SeqCst);
    let (out, _) = push(&folder, &["--to", &url]);
    assert!(out.status.success(), "{}", report(&out));
    assert_eq!(
        *received.lock().unwrap(),
        [33, 17],
        "the 16 confirmed were sent again"
    );
}

/// The finding: `user:pass` in a `--to` URL ended up in the push log's file name. The
/// credentials go into the Authorization header only: no file name, no log line, no message
/// holds them.
#[test]
fn credentials_in_a_to_url_are_never_written_to_disk() {
    let dir = tempfile::tempdir().unwrap();
    let (folder, uids) = instances(dir.path(), 2);
    // The head is read in lower case: base64 of `operator:s3cret pass`, lowered.
    let expected = "authorization: basic b3BlcmF0b3I6czNjcmV0IHBhc3M=".to_ascii_lowercase();
    let port = serve(move |head, _, stream| {
        let (status, answer) = if head.contains(&expected) {
            ("200 OK", stow_answer(&uids))
        } else {
            ("401 Unauthorized", String::new())
        };
        let _ = write!(
            stream,
            "HTTP/1.1 {status}\r\nContent-Type: application/dicom+json\r\nContent-Length: {}\r\n\r\n{answer}",
            answer.len()
        );
    });
    let url = format!("http://operator:s3cret%20pass@127.0.0.1:{port}/dicom-web");
    let (out, _) = push(&folder, &["--to", &url]);
    assert!(out.status.success(), "{}", report(&out));
    let shown = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!shown.contains("s3cret"), "{shown}");
    for entry in std::fs::read_dir(folder.join("pacs")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        assert!(
            !name.contains("s3cret") && !name.contains("operator"),
            "{name}"
        );
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(!text.contains("s3cret"), "{name}: {text}");
        assert_eq!(text.matches("\"kind\":\"stored\"").count(), 2, "{text}");
    }
}

/// The finding: a PACS's error text reached the terminal raw, escape sequences included (a
/// title change, a clear screen): `push` prints it escaped.
#[test]
fn pacs_error_text_reaches_the_terminal_escaped() {
    let dir = tempfile::tempdir().unwrap();
    let (folder, _) = instances(dir.path(), 1);
    let port = serve(move |_, _, stream| {
        let body = "\u{1b}]0;owned\u{7}\u{1b}[2J\u{202e}gnorw";
        let _ = write!(
            stream,
            "HTTP/1.1 500 Internal Server Error\r\nContent-Type: text/plain\r\nContent-Length: {}\r\n\r\n{body}",
            body.len()
        );
    });
    let url = format!("http://127.0.0.1:{port}/dicom-web");
    let (out, _) = push(&folder, &["--to", &url]);
    assert_eq!(out.status.code(), Some(1), "{}", report(&out));
    let shown = String::from_utf8_lossy(&out.stderr);
    assert!(shown.contains("HTTP 500"), "{shown}");
    assert!(
        !shown.contains('\u{1b}') && !shown.contains('\u{7}') && !shown.contains('\u{202e}'),
        "{shown:?}"
    );
    assert!(shown.contains("\\u{1b}]0;owned"), "{shown}");
}
