//! How a mock server started from a shell or a test is stopped: Ctrl-C, or its standard input
//! closing (a test that started it drops the pipe; a script closes it), unless asked to ignore
//! stdin.

/// " or closing stdin" unless the server ignores its stdin: the end of "Ctrl-C… stops it".
pub fn or_closing_stdin(ignore_stdin: bool) -> &'static str {
    if ignore_stdin {
        ""
    } else {
        " or closing stdin"
    }
}

/// Waits until Ctrl-C, or until stdin closes unless `ignore_stdin`.
pub async fn until_stopped(ignore_stdin: bool) {
    let stdin_closed = async {
        if ignore_stdin {
            std::future::pending::<()>().await;
        }
        let mut sink = Vec::new();
        let _ = tokio::io::AsyncReadExt::read_to_end(&mut tokio::io::stdin(), &mut sink).await;
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        () = stdin_closed => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_message_says_stdin_stops_the_server_unless_it_is_ignored() {
        assert_eq!(or_closing_stdin(false), " or closing stdin");
        assert_eq!(or_closing_stdin(true), "");
    }
}
