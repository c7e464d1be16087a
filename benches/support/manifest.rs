//! The build manifest the benchmarks' live series are written under.

use layerwise::build_dir::BuildManifest;
use layerwise::shot::View;

/// A fixed manifest for `views` (constant UIDs: a benchmark's output is thrown away).
pub fn bench_manifest(views: &[View]) -> BuildManifest {
    BuildManifest {
        name: "bench".into(),
        id: "bench".into(),
        created_at: chrono::Utc::now(),
        layers_expected: None,
        views: views.iter().map(|v| v.to_string()).collect(),
        study_instance_uid: "2.25.1".into(),
        frame_of_reference_uid: "2.25.2".into(),
        software_version: "bench".into(),
    }
}
