//! Why the OPC UA server did not start.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum OpcuaError {
    #[error("cannot read the OPC UA users file {}", path.display())]
    UsersRead {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "{} line {line}: expected `user:password` (a user name of letters, digits, `.`, `-`, `_`, \
         and a password of 8 or more characters)",
        path.display()
    )]
    UsersInvalid { path: PathBuf, line: usize },
    #[error("{} holds no user: add a `user:password` line", path.display())]
    NoUsers { path: PathBuf },
    #[error("cannot set up the OPC UA server: {0}")]
    Setup(String),
    #[error("cannot start the OPC UA server's thread")]
    Thread(#[source] std::io::Error),
}
