//! The real camera through libgphoto2 (the `gphoto2` crate). Only the camera actor's thread
//! touches it. Settings are applied at open: capture target RAM, format, exposure, manual focus.

use super::{Camera, CameraError, DriverError, Frame};
use crate::config::Gphoto2Config;
use crate::shot::Shot;
use gphoto2::error::ErrorKind;
use gphoto2::widget::Widget;
use std::collections::BTreeMap;
use std::time::Instant;
use tracing::info;

/// A libgphoto2 error with its kind.
#[derive(Debug, thiserror::Error)]
#[error("libgphoto2 {kind}")]
struct Gphoto {
    kind: String,
    #[source]
    source: gphoto2::Error,
}

/// How a libgphoto2 error is handled: retried, reopened, or failed; `said` is what the driver
/// said, carried as the error's source.
pub fn classify(kind: ErrorKind, message: &str, said: DriverError) -> CameraError {
    let lower = message.to_ascii_lowercase();
    // Nikon bodies report "device busy" as PTP 0x2019 or vendor codes 0xA2xx; libgphoto2 maps the
    // first to GP_ERROR_CAMERA_BUSY but may pass the vendor ones through as text.
    let vendor_busy = lower.contains("0xa2") || lower.contains("0x2019") || lower.contains("busy");
    let text = said;
    match kind {
        ErrorKind::CameraBusy => CameraError::Busy(text),
        _ if vendor_busy => CameraError::Busy(text),
        ErrorKind::Timeout => CameraError::Timeout(text),
        ErrorKind::IoUsbFind
        | ErrorKind::IoUsbClaim
        | ErrorKind::IoUsbClearHalt
        | ErrorKind::Io
        | ErrorKind::IoRead
        | ErrorKind::IoWrite
        | ErrorKind::IoLock
        | ErrorKind::UnknownPort
        | ErrorKind::ModelNotFound => CameraError::Disconnected(text),
        _ => CameraError::Failed(text),
    }
}

fn map(e: gphoto2::Error) -> CameraError {
    let (kind, message) = (e.kind(), e.to_string());
    let said = DriverError::of(Gphoto {
        kind: format!("{kind:?}"),
        source: e,
    });
    classify(kind, &message, said)
}

/// How a configured setting is written into a widget of a given type.
#[derive(Clone, Debug, PartialEq)]
pub enum SettingValue {
    Text(String),
    Choice(String),
    Range(f32),
    Toggle(bool),
}

/// Kinds of widget a setting can target.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WidgetKind {
    Text,
    Choice,
    Range,
    Toggle,
    Other,
}

/// Parses the configured text for a widget kind, naming the key on error.
pub fn parse_setting(key: &str, kind: WidgetKind, text: &str) -> Result<SettingValue, CameraError> {
    let bad = |message: String| CameraError::Setting {
        key: key.to_string(),
        message,
    };
    match kind {
        WidgetKind::Text => Ok(SettingValue::Text(text.to_string())),
        WidgetKind::Choice => Ok(SettingValue::Choice(text.to_string())),
        WidgetKind::Range => text
            .trim()
            .parse::<f32>()
            .map(SettingValue::Range)
            .map_err(|_| bad(format!("expected a number, found {text:?}"))),
        WidgetKind::Toggle => match text.trim().to_ascii_lowercase().as_str() {
            "1" | "on" | "true" | "yes" => Ok(SettingValue::Toggle(true)),
            "0" | "off" | "false" | "no" => Ok(SettingValue::Toggle(false)),
            _ => Err(bad(format!("expected on/off, found {text:?}"))),
        },
        WidgetKind::Other => Err(bad(
            "this setting cannot be written (a group, button or date)".into(),
        )),
    }
}

pub struct GphotoCamera {
    config: Gphoto2Config,
    context: gphoto2::Context,
    camera: gphoto2::Camera,
    description: String,
}

impl GphotoCamera {
    pub fn open(config: &Gphoto2Config) -> Result<GphotoCamera, CameraError> {
        let context = gphoto2::Context::new().map_err(map)?;
        let (camera, description) = Self::connect(&context, config)?;
        let camera = GphotoCamera {
            config: config.clone(),
            context,
            camera,
            description,
        };
        camera.apply_settings()?;
        info!(camera = %camera.description, "camera: open, settings applied");
        Ok(camera)
    }

    fn connect(
        context: &gphoto2::Context,
        config: &Gphoto2Config,
    ) -> Result<(gphoto2::Camera, String), CameraError> {
        if config.model.is_empty() && config.port.is_empty() {
            let camera = context.autodetect_camera().wait().map_err(map)?;
            let description = camera.abilities().model().to_string();
            return Ok((camera, description));
        }
        let found: Vec<_> = context.list_cameras().wait().map_err(map)?.collect();
        let descriptor = found
            .iter()
            .find(|d| (config.model.is_empty() || d.model == config.model) && (config.port.is_empty() || d.port == config.port))
            .ok_or_else(|| {
                let seen: Vec<String> = found.iter().map(|d| format!("{} on {}", d.model, d.port)).collect();
                CameraError::Disconnected(DriverError::said(format!(
                    "no camera {:?} on port {:?}; libgphoto2 sees: [{}]. Check the USB cable, that the body is on, \
                     and that gvfs has not claimed it",
                    config.model,
                    config.port,
                    seen.join(", ")
                )))
            })?;
        let camera = context.get_camera(descriptor).wait().map_err(map)?;
        Ok((
            camera,
            format!("{} on {}", descriptor.model, descriptor.port),
        ))
    }

    fn apply_settings(&self) -> Result<(), CameraError> {
        for (key, text) in &self.config.settings {
            let widget = self.camera.config_key::<Widget>(key).wait().map_err(|e| {
                CameraError::SettingRefused {
                    key: key.clone(),
                    hint: " (`gphoto2 --list-config` lists the names this body knows)",
                    source: DriverError::of(e),
                }
            })?;
            let kind = match &widget {
                Widget::Text(_) => WidgetKind::Text,
                Widget::Radio(_) => WidgetKind::Choice,
                Widget::Range(_) => WidgetKind::Range,
                Widget::Toggle(_) => WidgetKind::Toggle,
                _ => WidgetKind::Other,
            };
            let setting_error = |e: gphoto2::Error| CameraError::SettingRefused {
                key: key.clone(),
                hint: "",
                source: DriverError::of(e),
            };
            match (&widget, parse_setting(key, kind, text)?) {
                (Widget::Text(w), SettingValue::Text(v)) => {
                    w.set_value(&v).map_err(setting_error)?
                }
                (Widget::Radio(w), SettingValue::Choice(v)) => {
                    // libgphoto2 stores any string in a radio widget; a typo must not pass silently.
                    let choices: Vec<String> = w.choices_iter().collect();
                    if !choices.contains(&v) {
                        return Err(CameraError::Setting {
                            key: key.clone(),
                            message: format!(
                                "{v:?} is not one of the camera's choices: {}",
                                choices.join(", ")
                            ),
                        });
                    }
                    w.set_choice(&v).map_err(setting_error)?
                }
                (Widget::Range(w), SettingValue::Range(v)) => w.set_value(v),
                (Widget::Toggle(w), SettingValue::Toggle(v)) => w.set_toggled(v),
                _ => continue,
            }
            self.camera
                .set_config(&widget)
                .wait()
                .map_err(setting_error)?;
        }
        Ok(())
    }
}

/// The extension an original keeps, from the name the camera gave the file: lower case, `jpg`
/// for JPEGs (`DSC_0001.JPG`), `nef` for the D810's raw frames (`DSC_0001.NEF`).
fn frame_extension(camera_name: &str) -> String {
    let extension = std::path::Path::new(camera_name)
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_else(|| "jpg".into());
    if extension == "jpeg" {
        "jpg".into()
    } else {
        extension
    }
}

impl Camera for GphotoCamera {
    fn capture(&mut self, shot: &Shot) -> Result<Frame, CameraError> {
        tracing::debug!(layer = shot.layer, phase = %shot.phase, light = %shot.light, "gphoto2: capture");
        let started = Instant::now();
        let path = self.camera.capture_image().wait().map_err(map)?;
        let captured = Instant::now();
        let (folder, name) = (path.folder().to_string(), path.name().to_string());
        let file = self
            .camera
            .fs()
            .download(&folder, &name)
            .wait()
            .map_err(map)?;
        let data = file.get_data(&self.context).wait().map_err(map)?.into_vec();
        let downloaded = Instant::now();
        // Frees the camera's RAM buffer; a failure here does not lose the frame we hold.
        let _ = self.camera.fs().delete_file(&folder, &name).wait();
        Ok(Frame {
            data,
            extension: frame_extension(&name),
            capture_ms: (captured - started).as_secs_f64() * 1e3,
            download_ms: (downloaded - captured).as_secs_f64() * 1e3,
        })
    }

    fn reopen(&mut self) -> Result<(), CameraError> {
        let (camera, description) = Self::connect(&self.context, &self.config)?;
        self.camera = camera;
        self.description = description;
        self.apply_settings()
    }

    fn settings(&self) -> BTreeMap<String, String> {
        let mut s = self.config.settings.clone();
        s.insert("model".into(), self.description.clone());
        s
    }

    fn describe(&self) -> String {
        self.description.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_map_to_retry_classes() {
        assert!(matches!(
            classify(
                ErrorKind::CameraBusy,
                "Device Busy",
                DriverError::said("Device Busy")
            ),
            CameraError::Busy(_)
        ));
        assert!(matches!(
            classify(
                ErrorKind::Other,
                "PTP I/O Error 0xa201",
                DriverError::said("PTP I/O Error 0xa201")
            ),
            CameraError::Busy(_)
        ));
        assert!(matches!(
            classify(ErrorKind::Timeout, "timeout", DriverError::said("timeout")),
            CameraError::Timeout(_)
        ));
        assert!(matches!(
            classify(
                ErrorKind::IoUsbFind,
                "Could not find USB device",
                DriverError::said("Could not find USB device")
            ),
            CameraError::Disconnected(_)
        ));
        assert!(matches!(
            classify(ErrorKind::ModelNotFound, "x", DriverError::said("x")),
            CameraError::Disconnected(_)
        ));
        assert!(matches!(
            classify(ErrorKind::CorruptedData, "bad", DriverError::said("bad")),
            CameraError::Failed(_)
        ));
    }

    #[test]
    fn originals_keep_the_camera_file_type() {
        assert_eq!(frame_extension("DSC_0001.NEF"), "nef");
        assert_eq!(frame_extension("DSC_0001.JPG"), "jpg");
        assert_eq!(frame_extension("capt0000.jpeg"), "jpg");
        assert_eq!(frame_extension("capt0000"), "jpg");
    }

    #[test]
    fn settings_parse_by_widget_kind() {
        assert_eq!(
            parse_setting("iso", WidgetKind::Choice, "200").unwrap(),
            SettingValue::Choice("200".into())
        );
        assert_eq!(
            parse_setting("zoom", WidgetKind::Range, " 2.5 ").unwrap(),
            SettingValue::Range(2.5)
        );
        assert_eq!(
            parse_setting("viewfinder", WidgetKind::Toggle, "Off").unwrap(),
            SettingValue::Toggle(false)
        );
        let err = parse_setting("viewfinder", WidgetKind::Toggle, "maybe")
            .unwrap_err()
            .to_string();
        assert!(err.contains("viewfinder") && err.contains("maybe"), "{err}");
        assert!(parse_setting("zoom", WidgetKind::Range, "x").is_err());
        assert!(parse_setting("main", WidgetKind::Other, "x").is_err());
    }
}
