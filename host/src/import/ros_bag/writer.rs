//! Writes ROS2 bags: a folder holding one MCAP file (the `ros2` profile, CDR messages,
//! `ros2msg` schemas, zstd-compressed chunks, with the summary and indexes `ros2 bag info`
//! reads) and its `metadata.yaml` (rosbag2's version 5, which Humble and later read), written
//! with the `mcap` crate. The folder is written whole or not at all.

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use super::messages::ros2_definitions;
use crate::output::FileSet;

/// Errors of the writer, each naming the bag.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BagWriteError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: MCAP: {message}")]
    Mcap { path: PathBuf, message: String },
    #[error("{path}: no ros2msg definition for {msg_type}")]
    UnknownType { path: PathBuf, msg_type: String },
}

struct Topic {
    name: String,
    msg_type: String,
    channel: u16,
    count: u64,
}

/// A ROS2 bag being written.
pub struct Ros2BagWriter {
    dir: PathBuf,
    set: FileSet,
    file_name: String,
    mcap: mcap::Writer<BufWriter<std::fs::File>>,
    schemas: BTreeMap<String, u16>,
    topics: Vec<Topic>,
    /// First and last log time, ns since the Unix epoch.
    span_ns: Option<(u64, u64)>,
}

impl Ros2BagWriter {
    /// Starts the bag folder `dir` (created if absent; its previous bag, if any, stays until
    /// [`Ros2BagWriter::finish`]).
    pub fn create(dir: &Path) -> Result<Self, BagWriteError> {
        let io = |source| BagWriteError::Io {
            path: dir.to_path_buf(),
            source,
        };
        let mut set = FileSet::create(dir, Some("metadata.yaml")).map_err(io)?;
        let stem = dir
            .file_name()
            .map_or("bag".into(), |n| n.to_string_lossy().into_owned());
        let file_name = format!("{stem}_0.mcap");
        let file = std::fs::File::create(set.path(&file_name)).map_err(io)?;
        let mcap = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("dynacal ", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Zstd))
            .create(BufWriter::new(file))
            .map_err(|e| BagWriteError::Mcap {
                path: dir.to_path_buf(),
                message: e.to_string(),
            })?;
        Ok(Self {
            dir: dir.to_path_buf(),
            set,
            file_name,
            mcap,
            schemas: BTreeMap::new(),
            topics: Vec::new(),
            span_ns: None,
        })
    }

    fn mcap_error(&self, e: impl std::fmt::Display) -> BagWriteError {
        BagWriteError::Mcap {
            path: self.dir.clone(),
            message: e.to_string(),
        }
    }

    /// Adds a topic of `msg_type` (`sensor_msgs/msg/Imu`, `sensor_msgs/msg/NavSatFix`,
    /// `nav_msgs/msg/Odometry`); returns its index for [`Ros2BagWriter::write`].
    pub fn add_topic(&mut self, name: &str, msg_type: &str) -> Result<usize, BagWriteError> {
        let schema = match self.schemas.get(msg_type) {
            Some(id) => *id,
            None => {
                let (_, definition) = ros2_definitions()
                    .into_iter()
                    .find(|(t, _)| *t == msg_type)
                    .ok_or_else(|| BagWriteError::UnknownType {
                        path: self.dir.clone(),
                        msg_type: msg_type.into(),
                    })?;
                let id = self
                    .mcap
                    .add_schema(msg_type, "ros2msg", definition.as_bytes())
                    .map_err(|e| self.mcap_error(e))?;
                self.schemas.insert(msg_type.into(), id);
                id
            }
        };
        let metadata = BTreeMap::from([("offered_qos_profiles".to_string(), String::new())]);
        let channel = self
            .mcap
            .add_channel(schema, name, "cdr", &metadata)
            .map_err(|e| self.mcap_error(e))?;
        self.topics.push(Topic {
            name: name.into(),
            msg_type: msg_type.into(),
            channel,
            count: 0,
        });
        Ok(self.topics.len() - 1)
    }

    /// Writes one serialised message of `topic` logged at `log_time_ns` (ns since the Unix
    /// epoch).
    pub fn write(
        &mut self,
        topic: usize,
        log_time_ns: u64,
        data: &[u8],
    ) -> Result<(), BagWriteError> {
        let t = &mut self.topics[topic];
        let header = mcap::records::MessageHeader {
            channel_id: t.channel,
            sequence: t.count as u32,
            log_time: log_time_ns,
            publish_time: log_time_ns,
        };
        t.count += 1;
        self.span_ns = Some(match self.span_ns {
            None => (log_time_ns, log_time_ns),
            Some((a, b)) => (a.min(log_time_ns), b.max(log_time_ns)),
        });
        self.mcap
            .write_to_known_channel(&header, data)
            .map_err(|e| self.mcap_error(e))
    }

    /// Finishes the MCAP file, writes `metadata.yaml` and moves both into the folder.
    pub fn finish(mut self) -> Result<Vec<PathBuf>, BagWriteError> {
        self.mcap.finish().map_err(|e| self.mcap_error(e))?;
        let yaml = self.metadata_yaml();
        let io = |source| BagWriteError::Io {
            path: self.dir.clone(),
            source,
        };
        std::fs::write(self.set.path("metadata.yaml"), yaml).map_err(io)?;
        drop(self.mcap);
        self.set.commit().map_err(io)
    }

    fn metadata_yaml(&self) -> String {
        use std::fmt::Write as _;
        let (start, end) = self.span_ns.unwrap_or((0, 0));
        let total: u64 = self.topics.iter().map(|t| t.count).sum();
        let mut y = String::from(
            "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n",
        );
        let _ = write!(
            y,
            "  duration:\n    nanoseconds: {}\n  starting_time:\n    nanoseconds_since_epoch: {start}\n  message_count: {total}\n  topics_with_message_count:\n",
            end - start
        );
        for t in &self.topics {
            let _ = write!(
                y,
                "    - topic_metadata:\n        name: {}\n        type: {}\n        serialization_format: cdr\n        offered_qos_profiles: \"\"\n      message_count: {}\n",
                t.name, t.msg_type, t.count
            );
        }
        let _ = write!(
            y,
            "  compression_format: \"\"\n  compression_mode: \"\"\n  relative_file_paths:\n    - {0}\n  files:\n    - path: {0}\n      starting_time:\n        nanoseconds_since_epoch: {start}\n      duration:\n        nanoseconds: {1}\n      message_count: {total}\n",
            self.file_name,
            end - start
        );
        y
    }
}
