//! Admission, eviction and timeouts on in-memory streams under tokio's paused clock (the
//! durations are the simulated clock's, exact up to one sweep), and the two adapters on real
//! loopback sockets.

use std::convert::Infallible;
use std::io::ErrorKind;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};
use tokio::task::JoinHandle;
use tokio::time::{Instant, sleep};
use tower::{Service, ServiceExt};

use crate::{
    Admission, AdmitOn, CloseReason, Conn, ConnIo, ConnLayer, ConnLimits, ConnService, Refused,
};

fn peer(s: &str) -> SocketAddr {
    s.parse().unwrap()
}

fn limits() -> ConnLimits {
    ConnLimits {
        handshake_timeout: Duration::from_secs(10),
        idle_timeout: Duration::from_secs(60),
        ..ConnLimits::default()
    }
}

/// A server end admitted from `addr` and wrapped, and the client end.
fn connect(adm: &Arc<Admission>, addr: &str) -> (ConnIo<DuplexStream>, DuplexStream) {
    let conn = adm.admit("test", peer(addr)).unwrap();
    let (client, server) = tokio::io::duplex(64);
    (ConnIo::new(server, conn), client)
}

/// Echoes the client's bytes until a read or write fails (or the client hangs up); returns
/// the failure's kind (`None` for a hang-up) and when it came.
fn echo(mut io: ConnIo<DuplexStream>) -> JoinHandle<(Option<ErrorKind>, Instant)> {
    tokio::spawn(async move {
        let mut buf = [0u8; 64];
        loop {
            let n = match io.read(&mut buf).await {
                Ok(0) => return (None, Instant::now()),
                Ok(n) => n,
                Err(e) => return (Some(e.kind()), Instant::now()),
            };
            if let Err(e) = io.write_all(&buf[..n]).await {
                return (Some(e.kind()), Instant::now());
            }
        }
    })
}

/// The client sends a byte and reads its echo every `every`, `times` times.
async fn chat(client: &mut DuplexStream, every: Duration, times: usize) {
    for _ in 0..times {
        sleep(every).await;
        client.write_all(b"x").await.unwrap();
        let mut b = [0u8; 1];
        client.read_exact(&mut b).await.unwrap();
    }
}

fn within_one_sweep(closed: Instant, due: Instant, l: &ConnLimits) {
    assert!(closed >= due, "closed {:?} early", due - closed);
    assert!(
        closed <= due + l.sweep_interval(),
        "closed {:?} late",
        closed - due
    );
}

#[tokio::test(start_paused = true)]
async fn a_silent_connection_is_closed_at_the_handshake_timeout() {
    let adm = Admission::start(limits(), AdmitOn::Authenticated);
    let start = Instant::now();
    let (io, _client) = connect(&adm, "10.0.0.1:5000");
    let conn = io.conn().clone();
    assert_eq!((adm.open(), adm.unauthenticated()), (1, 1));
    let (kind, at) = echo(io).await.unwrap();
    assert_eq!(kind, Some(ErrorKind::TimedOut));
    within_one_sweep(at, start + Duration::from_secs(10), adm.limits());
    assert_eq!(conn.close_reason(), Some(CloseReason::HandshakeTimeout));
    // The stream dropped with the task: the registry forgot it.
    assert_eq!((adm.open(), adm.unauthenticated()), (0, 0));
}

#[tokio::test(start_paused = true)]
async fn bytes_do_not_extend_the_handshake_timeout() {
    // A slow header: bytes keep coming but no request is ever admitted.
    let adm = Admission::start(limits(), AdmitOn::Authenticated);
    let start = Instant::now();
    let (io, mut client) = connect(&adm, "10.0.0.1:5000");
    let conn = io.conn().clone();
    let server = echo(io);
    let trickle = tokio::spawn(async move {
        let mut b = [0u8; 1];
        loop {
            sleep(Duration::from_secs(1)).await;
            if client.write_all(b"x").await.is_err() || client.read_exact(&mut b).await.is_err() {
                return;
            }
        }
    });
    let (kind, at) = server.await.unwrap();
    assert_eq!(kind, Some(ErrorKind::TimedOut));
    within_one_sweep(at, start + Duration::from_secs(10), adm.limits());
    assert_eq!(conn.close_reason(), Some(CloseReason::HandshakeTimeout));
    trickle.await.unwrap();
}

#[tokio::test(start_paused = true)]
async fn an_authenticated_connection_lives_while_active_then_idles_out() {
    let adm = Admission::start(limits(), AdmitOn::Authenticated);
    let (io, mut client) = connect(&adm, "10.0.0.1:5000");
    let conn = io.conn().clone();
    conn.mark_authenticated();
    assert_eq!(adm.unauthenticated(), 0);
    let server = echo(io);
    // Well past both timeouts, with a byte every 50 s (< idle 60 s).
    chat(&mut client, Duration::from_secs(50), 6).await;
    assert!(!server.is_finished());
    assert_eq!(conn.close_reason(), None);
    let last = Instant::now();
    let (kind, at) = server.await.unwrap();
    assert_eq!(kind, Some(ErrorKind::TimedOut));
    within_one_sweep(at, last + Duration::from_secs(60), adm.limits());
    assert_eq!(conn.close_reason(), Some(CloseReason::IdleTimeout));
    // The client sees the end of the stream.
    let mut b = [0u8; 1];
    assert_eq!(client.read(&mut b).await.unwrap(), 0);
}

#[tokio::test(start_paused = true)]
async fn a_request_in_flight_keeps_a_silent_connection_open() {
    // A reconstruction answering after 5 minutes, no byte meanwhile.
    let adm = Admission::start(limits(), AdmitOn::AnyRequest);
    let (io, _client) = connect(&adm, "10.0.0.1:5000");
    let conn = io.conn().clone();
    let server = echo(io);
    let slow = tower::service_fn(|_req: http::Request<()>| async {
        sleep(Duration::from_secs(300)).await;
        Ok::<_, Infallible>(())
    });
    let mut svc = ConnService::for_conn(slow, conn.clone());
    let call = svc.ready().await.unwrap().call(http::Request::new(()));
    // Any request admits on a server without a token.
    assert!(conn.is_admitted());
    call.await.unwrap();
    assert!(!server.is_finished(), "closed during the request");
    let done = Instant::now();
    let (kind, at) = server.await.unwrap();
    assert_eq!(kind, Some(ErrorKind::TimedOut));
    within_one_sweep(at, done + Duration::from_secs(60), adm.limits());
    assert_eq!(conn.close_reason(), Some(CloseReason::IdleTimeout));
}

#[tokio::test(start_paused = true)]
async fn only_the_access_check_admits_when_a_token_is_required() {
    let adm = Admission::new(limits(), AdmitOn::Authenticated);
    let (io, _client) = connect(&adm, "10.0.0.1:5000");
    let conn = io.conn().clone();
    // ConnLayer finds the handle in the extensions (as tonic puts it there) and passes it on.
    let inner = tower::service_fn(|req: http::Request<()>| async move {
        Ok::<_, Infallible>(req.extensions().get::<Conn>().is_some())
    });
    let mut svc = tower::Layer::layer(&ConnLayer, inner);
    let mut req = http::Request::new(());
    req.extensions_mut().insert(conn.clone());
    assert!(svc.ready().await.unwrap().call(req).await.unwrap());
    assert!(!conn.is_admitted());
    assert_eq!(adm.unauthenticated(), 1);
    // A request without a handle passes untouched.
    let bare = svc.ready().await.unwrap().call(http::Request::new(()));
    assert!(!bare.await.unwrap());
    conn.mark_authenticated();
    assert!(conn.is_admitted());
    assert_eq!(adm.unauthenticated(), 0);
}

#[tokio::test(start_paused = true)]
async fn the_oldest_unauthenticated_connection_makes_room() {
    let adm = Admission::new(
        ConnLimits {
            max_unauthenticated: 3,
            ..limits()
        },
        AdmitOn::Authenticated,
    );
    let (a, mut aclient) = connect(&adm, "10.0.0.1:1");
    let a_conn = a.conn().clone();
    // `a`'s server end is blocked writing to a client that does not read.
    let writer = tokio::spawn(async move {
        let mut a = a;
        a.write_all(&[0u8; 4096]).await.map_err(|e| e.kind())
    });
    let b = adm.admit("test", peer("10.0.0.2:1")).unwrap();
    let c = adm.admit("test", peer("10.0.0.3:1")).unwrap();
    tokio::task::yield_now().await;
    assert!(!writer.is_finished());
    let d = adm.admit("test", peer("10.0.0.4:1")).unwrap();
    assert_eq!(a_conn.close_reason(), Some(CloseReason::Evicted));
    assert_eq!(writer.await.unwrap(), Err(ErrorKind::ConnectionAborted));
    let mut rest = Vec::new();
    aclient.read_to_end(&mut rest).await.unwrap();
    for k in [&b, &c, &d] {
        assert_eq!(k.close_reason(), None);
    }
    assert_eq!((adm.open(), adm.unauthenticated()), (3, 3));
    // An authenticated connection is never evicted: the next oldest unauthenticated one is.
    b.mark_authenticated();
    let e = adm.admit("test", peer("10.0.0.5:1")).unwrap();
    assert_eq!(adm.unauthenticated(), 3);
    let _f = adm.admit("test", peer("10.0.0.6:1")).unwrap();
    assert_eq!(b.close_reason(), None);
    assert_eq!(c.close_reason(), Some(CloseReason::Evicted));
    assert_eq!((d.close_reason(), e.close_reason()), (None, None));
    // A closed connection stays closed.
    c.mark_authenticated();
    assert!(!c.is_admitted());
}

#[tokio::test(start_paused = true)]
async fn the_per_ip_cap_evicts_that_address_then_refuses() {
    let adm = Admission::new(
        ConnLimits {
            max_per_ip: 2,
            ..limits()
        },
        AdmitOn::Authenticated,
    );
    let a1 = adm.admit("test", peer("10.0.0.1:1")).unwrap();
    let b1 = adm.admit("test", peer("10.0.0.2:1")).unwrap();
    let a2 = adm.admit("test", peer("10.0.0.1:2")).unwrap();
    let a3 = adm.admit("test", peer("10.0.0.1:3")).unwrap();
    assert_eq!(a1.close_reason(), Some(CloseReason::Evicted));
    assert_eq!(
        b1.close_reason(),
        None,
        "another address' connection was evicted"
    );
    a2.mark_authenticated();
    a3.mark_authenticated();
    assert_eq!(
        adm.admit("test", peer("10.0.0.1:4")).unwrap_err(),
        Refused::MaxPerIp(2)
    );
    assert!(adm.admit("test", peer("10.0.0.2:2")).is_ok());
    // IPv6 counts per /64; an IPv4-mapped address is its IPv4 address.
    let v6a = adm.admit("test", peer("[2001:db8::1]:1")).unwrap();
    let _v6b = adm.admit("test", peer("[2001:db8::2]:1")).unwrap();
    let other64 = adm.admit("test", peer("[2001:db8:0:1::1]:1")).unwrap();
    let _v6c = adm.admit("test", peer("[2001:db8::3]:1")).unwrap();
    assert_eq!(v6a.close_reason(), Some(CloseReason::Evicted));
    assert_eq!(other64.close_reason(), None);
    assert_eq!(
        adm.admit("test", peer("[::ffff:10.0.0.1]:9")).unwrap_err(),
        Refused::MaxPerIp(2)
    );
}

#[tokio::test(start_paused = true)]
async fn the_global_cap_refuses_only_when_every_connection_is_admitted() {
    let adm = Admission::new(
        ConnLimits {
            max_connections: 2,
            max_per_ip: 2,
            ..limits()
        },
        AdmitOn::Authenticated,
    );
    let (x, _xc) = connect(&adm, "10.0.0.1:1");
    x.conn().mark_authenticated();
    let y = adm.admit("test", peer("10.0.0.2:1")).unwrap();
    // y is unauthenticated: it makes room.
    let (z, _zc) = connect(&adm, "10.0.0.3:1");
    assert_eq!(y.close_reason(), Some(CloseReason::Evicted));
    assert_eq!(x.conn().close_reason(), None);
    z.conn().mark_authenticated();
    assert_eq!(
        adm.admit("test", peer("10.0.0.4:1")).unwrap_err(),
        Refused::MaxConnections(2)
    );
    // A connection that ends frees its slot.
    drop(x);
    assert_eq!(adm.open(), 1);
    assert!(adm.admit("test", peer("10.0.0.4:1")).is_ok());
}

#[tokio::test]
async fn incoming_admits_wraps_and_closes_refused_connections() {
    use tokio_stream::StreamExt;
    use tonic::transport::server::Connected;

    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let adm = Admission::new(
        ConnLimits {
            max_connections: 1,
            max_per_ip: 1,
            ..limits()
        },
        AdmitOn::Authenticated,
    );
    let mut incoming = crate::ConnIncoming::new(
        tokio_stream::wrappers::TcpListenerStream::new(listener),
        Arc::clone(&adm),
        "grpc",
    );
    let first = tokio::net::TcpStream::connect(addr).await.unwrap();
    let io = incoming.next().await.unwrap().unwrap();
    let conn = io.connect_info();
    assert_eq!(conn.peer(), first.local_addr().unwrap());
    conn.mark_authenticated();
    // The cap is full of admitted connections: the next one is closed unserved.
    let mut second = tokio::net::TcpStream::connect(addr).await.unwrap();
    let mut b = [0u8; 1];
    tokio::select! {
        read = second.read(&mut b) => assert!(matches!(read, Ok(0)) || read.is_err()),
        next = incoming.next() => panic!("a refused connection was served: {next:?}"),
    }
    assert_eq!(adm.open(), 1);
}

#[tokio::test]
async fn the_acceptor_wraps_stream_and_service() {
    use axum_server::accept::{Accept, DefaultAcceptor};

    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let adm = Admission::new(
        ConnLimits {
            max_connections: 1,
            max_per_ip: 1,
            ..limits()
        },
        AdmitOn::AnyRequest,
    );
    let acceptor = crate::ConnAcceptor::new(DefaultAcceptor, Arc::clone(&adm), "http");
    let svc = tower::service_fn(|req: http::Request<()>| async move {
        Ok::<_, Infallible>(req.extensions().get::<Conn>().map(Conn::peer))
    });
    let client = tokio::net::TcpStream::connect(addr).await.unwrap();
    let (stream, _) = listener.accept().await.unwrap();
    let (io, svc) = acceptor.accept(stream, svc).await.unwrap();
    assert!(io.get_ref().nodelay().unwrap());
    assert!(!io.conn().is_admitted());
    let seen = svc.oneshot(http::Request::new(())).await.unwrap();
    assert_eq!(seen, Some(client.local_addr().unwrap()));
    assert!(io.conn().is_admitted());
    // Full of admitted connections: refused.
    let _other = tokio::net::TcpStream::connect(addr).await.unwrap();
    let (stream, _) = listener.accept().await.unwrap();
    let refused = acceptor.accept(
        stream,
        tower::service_fn(|_: http::Request<()>| async { Ok::<_, Infallible>(None::<SocketAddr>) }),
    );
    assert!(refused.await.is_err());
}
