//! A pseudo-terminal pair standing in for a serial device in tests: the
//! code under test opens the slave path like a real port; the test writes
//! what the pad would send to the master.

/// A pseudo-terminal pair: the master plays the pad, the slave's path is the
/// "serial port".
pub struct Pty {
    /// The pad's end: what the test writes here, the code under test reads
    /// from `path`; dropping it is the pad unplugged.
    pub master: std::fs::File,
    /// Held open so the pair lives until the test drops it.
    _slave: std::fs::File,
    /// The slave's device path (`/dev/pts/N`), opened as the serial port.
    pub path: String,
}

/// Opens a pseudo-terminal pair with the slave in raw mode (no echo, no
/// line editing), so bytes written to the master before the port is opened
/// arrive as written. Panics when the system gives no pseudo-terminal.
pub fn open_pty() -> Pty {
    use std::os::fd::FromRawFd;
    let (mut master, mut slave) = (0, 0);
    // SAFETY: openpty writes two fds into the provided ints; the name, termios
    // and window-size pointers may be null.
    let rc = unsafe {
        libc::openpty(
            &mut master,
            &mut slave,
            std::ptr::null_mut(),
            std::ptr::null(),
            std::ptr::null(),
        )
    };
    assert_eq!(rc, 0, "openpty: {}", std::io::Error::last_os_error());
    // SAFETY: both fds were just opened by openpty and are owned by nobody else.
    let (master, slave) = unsafe {
        (
            std::fs::File::from_raw_fd(master),
            std::fs::File::from_raw_fd(slave),
        )
    };
    let path = std::fs::read_link(format!("/proc/self/fd/{}", {
        use std::os::fd::AsRawFd;
        slave.as_raw_fd()
    }))
    .expect("the slave's path")
    .to_string_lossy()
    .into_owned();
    // Raw mode before the port opens, so bytes written early are not echoed
    // or held back by the line discipline.
    {
        use std::os::fd::AsRawFd;
        // SAFETY: a zeroed termios is valid storage for tcgetattr to fill.
        let mut tio: libc::termios = unsafe { std::mem::zeroed() };
        // SAFETY: the fd is open and tio is valid.
        unsafe {
            assert_eq!(libc::tcgetattr(slave.as_raw_fd(), &mut tio), 0);
            libc::cfmakeraw(&mut tio);
            assert_eq!(libc::tcsetattr(slave.as_raw_fd(), libc::TCSANOW, &tio), 0);
        }
    }
    Pty {
        master,
        _slave: slave,
        path,
    }
}
