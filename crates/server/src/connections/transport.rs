//! An accepted connection's byte stream ([`Transport`]): plain TCP, or TLS from the sniff of its
//! first byte through the handshake.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpStream;
use tokio_rustls::TlsAcceptor;

/// The first bytes of a client that spoke plain HTTP to the TLS port, and the answer it gets: a
/// request line begins with a method's letters, a TLS connection with a handshake record (22).
const TLS_HANDSHAKE_RECORD: u8 = 0x16;
const PLAIN_HTTP_ANSWER: &[u8] = b"HTTP/1.1 400 Bad Request\r\n\
Content-Type: text/plain; charset=utf-8\r\n\
Connection: close\r\n\
Content-Length: 59\r\n\
\r\n\
this server speaks HTTPS only: use an https:// URL instead\n";

/// An accepted connection's byte stream: plain TCP, or TLS in its stages.
pub enum Transport {
    Plain(TcpStream),
    /// TLS, before the first byte: a handshake, or plain HTTP sent by mistake?
    Sniff(TcpStream, TlsAcceptor),
    Handshake(Box<tokio_rustls::Accept<TcpStream>>),
    Tls(Box<tokio_rustls::server::TlsStream<TcpStream>>),
    /// Plain HTTP on the TLS port: sending [`PLAIN_HTTP_ANSWER`] (from this offset), then closing.
    Refuse(TcpStream, usize),
    Closed,
}

impl Transport {
    /// Plain TCP, or TLS past its handshake: what it reads is HTTP.
    pub(super) fn is_established(&self) -> bool {
        matches!(self, Transport::Plain(_) | Transport::Tls(_))
    }

    /// Drives a TLS connection to its `Tls` stage (a no-op for the others); an error ends it.
    fn poll_established(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        loop {
            match self {
                Transport::Plain(_) | Transport::Tls(_) => return Poll::Ready(Ok(())),
                Transport::Sniff(io, acceptor) => {
                    let mut first = [0u8; 1];
                    let mut buf = ReadBuf::new(&mut first);
                    match io.poll_peek(cx, &mut buf) {
                        Poll::Pending => return Poll::Pending,
                        Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                        Poll::Ready(Ok(0)) => return Poll::Ready(Ok(())), // closed: EOF
                        Poll::Ready(Ok(_)) => {}
                    }
                    let acceptor = acceptor.clone();
                    let Transport::Sniff(io, _) = std::mem::replace(self, Transport::Closed) else {
                        unreachable!("matched above")
                    };
                    *self = if first[0] == TLS_HANDSHAKE_RECORD {
                        Transport::Handshake(Box::new(acceptor.accept(io)))
                    } else {
                        Transport::Refuse(io, 0)
                    };
                }
                Transport::Handshake(accept) => match Pin::new(accept.as_mut()).poll(cx) {
                    Poll::Pending => return Poll::Pending,
                    Poll::Ready(Ok(tls)) => *self = Transport::Tls(Box::new(tls)),
                    Poll::Ready(Err(e)) => {
                        *self = Transport::Closed;
                        tracing::debug!(error = %e, "TLS handshake failed");
                        return Poll::Ready(Err(e));
                    }
                },
                Transport::Refuse(io, sent) => {
                    while *sent < PLAIN_HTTP_ANSWER.len() {
                        match Pin::new(&mut *io).poll_write(cx, &PLAIN_HTTP_ANSWER[*sent..]) {
                            Poll::Pending => return Poll::Pending,
                            Poll::Ready(Ok(0)) | Poll::Ready(Err(_)) => break,
                            Poll::Ready(Ok(n)) => *sent += n,
                        }
                    }
                    if Pin::new(&mut *io).poll_shutdown(cx).is_pending() {
                        return Poll::Pending;
                    }
                    *self = Transport::Closed;
                    tracing::debug!("plain HTTP on the TLS port: answered 400 and closed");
                    return Poll::Ready(Err(io::Error::new(
                        io::ErrorKind::InvalidData,
                        "plain HTTP on the TLS port",
                    )));
                }
                Transport::Closed => {
                    return Poll::Ready(Err(io::ErrorKind::NotConnected.into()));
                }
            }
        }
    }
}

impl AsyncRead for Transport {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_established(cx))?;
        match this {
            Transport::Plain(io) => Pin::new(io).poll_read(cx, buf),
            Transport::Tls(io) => Pin::new(io.as_mut()).poll_read(cx, buf),
            // A connection closed before its first byte: end of file.
            _ => Poll::Ready(Ok(())),
        }
    }
}

impl AsyncWrite for Transport {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_established(cx))?;
        match this {
            Transport::Plain(io) => Pin::new(io).poll_write(cx, buf),
            Transport::Tls(io) => Pin::new(io.as_mut()).poll_write(cx, buf),
            _ => Poll::Ready(Err(io::ErrorKind::NotConnected.into())),
        }
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_established(cx))?;
        match this {
            Transport::Plain(io) => Pin::new(io).poll_write_vectored(cx, bufs),
            Transport::Tls(io) => Pin::new(io.as_mut()).poll_write_vectored(cx, bufs),
            _ => Poll::Ready(Err(io::ErrorKind::NotConnected.into())),
        }
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match self.get_mut() {
            Transport::Plain(io) => Pin::new(io).poll_flush(cx),
            Transport::Tls(io) => Pin::new(io.as_mut()).poll_flush(cx),
            _ => Poll::Ready(Ok(())),
        }
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match self.get_mut() {
            Transport::Plain(io) => Pin::new(io).poll_shutdown(cx),
            Transport::Tls(io) => Pin::new(io.as_mut()).poll_shutdown(cx),
            Transport::Sniff(io, _) | Transport::Refuse(io, _) => Pin::new(io).poll_shutdown(cx),
            Transport::Handshake(_) | Transport::Closed => Poll::Ready(Ok(())),
        }
    }
}
