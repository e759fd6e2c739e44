/*
 * simtime_io.c: the hooks of descriptors (see simtime.c): poll, epoll_wait and select with a timeout, blocking
 * receives and accept are sim-time waits; sends are counted (the runtime settles them before phase 0 ends).
 */
#include "simtime.h"

static int64_t ms_deadline(int ms) { return ms < 0 ? NO_DEADLINE : add_ns(sim_now(), (int64_t)ms * 1000000LL); }

int hs_poll(struct pollfd *fds, nfds_t n, int ms) {
    if (ms == 0 || !on_sim())
        return real_poll(fds, n, ms);
    int64_t deadline = ms_deadline(ms);
    tstate *t = hs__me();
    for (;;) {
        int r = real_poll(fds, n, 0);
        if (r != 0)
            return r;
        if (sim_wait(t, fds, (int)n, deadline, NULL, 0))
            return real_poll(fds, n, 0);
    }
}

int hs_epoll_wait(int ep, struct epoll_event *ev, int max, int ms) {
    if (ms == 0 || !on_sim())
        return epoll_wait(ep, ev, max, ms);
    int64_t deadline = ms_deadline(ms);
    tstate *t = hs__me();
    struct pollfd p = {.fd = ep, .events = POLLIN};
    for (;;) {
        int r = epoll_wait(ep, ev, max, 0);
        if (r != 0)
            return r;
        if (sim_wait(t, &p, 1, deadline, NULL, 0))
            return epoll_wait(ep, ev, max, 0);
    }
}

static int raw_select(int nfds, fd_set *r, fd_set *w, fd_set *e, struct timeval *tv) {
    return select(nfds, r, w, e, tv);
}

static int select_wait(void *t, struct pollfd *p, int n, int64_t deadline) {
    return hs__sim_wait_in(t, p, n, deadline, NULL, 0, "select");
}

int hs_select(int nfds, fd_set *r, fd_set *w, fd_set *e, struct timeval *tv) {
    if ((tv && tv->tv_sec == 0 && tv->tv_usec == 0) || !on_sim())
        return select(nfds, r, w, e, tv);
    int64_t deadline = tv ? add_ns(sim_now(), (int64_t)tv->tv_sec * 1000000000LL + (int64_t)tv->tv_usec * 1000) : NO_DEADLINE;
    return select_on_sim(nfds, r, w, e, deadline, raw_select, select_wait, hs__me());
}

static int nonblocking(int fd) { return (fcntl(fd, F_GETFL) & O_NONBLOCK) != 0; }

/* The socket's SO_RCVTIMEO as a sim deadline. */
static int64_t rcv_deadline(int fd) {
    struct timeval tv = {0, 0};
    socklen_t len = sizeof tv;
    if (getsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, &len) != 0 || (tv.tv_sec == 0 && tv.tv_usec == 0))
        return NO_DEADLINE;
    return add_ns(sim_now(), (int64_t)tv.tv_sec * 1000000000LL + (int64_t)tv.tv_usec * 1000);
}

/* Traced receives: the MAVLink frames of a datagram (message ids), to see in which phase each was read. */
static void trace_frames(const char *what, int fd, const unsigned char *b, ssize_t n) {
    if (!trace || n <= 0)
        return;
    char ids[256];
    size_t at = 0;
    ids[0] = 0;
    for (ssize_t i = 0; i + 10 <= n && at < sizeof ids - 16;) {
        if (b[i] != 0xFD) {
            i++;
            continue;
        }
        unsigned id = b[i + 7] | (unsigned)b[i + 8] << 8 | (unsigned)b[i + 9] << 16;
        at += (size_t)snprintf(ids + at, sizeof ids - at, " %u/%u", id, b[i + 4]);
        i += 12 + b[i + 1] + ((b[i + 2] & 1) ? 13 : 0);
    }
    pthread_mutex_lock(&mu);
    TRACE("%s fd=%d n=%zd%s", what, fd, n, ids);
    pthread_mutex_unlock(&mu);
}

/* A blocking receive: try without blocking, else wait (idle) for the socket on the sim clock. */
#define BLOCKING_RECV(fd, flags, call)                                                                    \
    do {                                                                                                  \
        if (((flags) & MSG_DONTWAIT) || nonblocking(fd))                                                 \
            return call((flags));                                                                         \
        int64_t deadline_ = rcv_deadline(fd);                                                             \
        struct pollfd p_ = {.fd = (fd), .events = POLLIN};                                                \
        tstate *t_ = hs__me();                                                                                \
        for (;;) {                                                                                        \
            ssize_t r_ = call((flags) | MSG_DONTWAIT);                                                    \
            if (r_ >= 0 || (errno != EAGAIN && errno != EWOULDBLOCK))                                     \
                return r_;                                                                                \
            if (sim_wait(t_, &p_, 1, deadline_, NULL, 0)) {                                               \
                errno = EAGAIN;                                                                           \
                return -1;                                                                                \
            }                                                                                             \
        }                                                                                                 \
    } while (0)

static ssize_t recv_traced(int fd, void *buf, size_t len, int flags) {
    ssize_t r = recv(fd, buf, len, flags);
    trace_frames("recv", fd, buf, r);
    return r;
}

static ssize_t recvfrom_traced(int fd, void *buf, size_t len, int flags, struct sockaddr *a, socklen_t *al) {
    ssize_t r = recvfrom(fd, buf, len, flags, a, al);
    trace_frames("recv", fd, buf, r);
    return r;
}

static int recvmmsg_traced(int fd, struct mmsghdr *v, unsigned int n, int flags) {
    int r = recvmmsg(fd, v, n, flags, NULL);
    for (int i = 0; i < r; i++)
        trace_frames("recv", fd, v[i].msg_hdr.msg_iov[0].iov_base, (ssize_t)v[i].msg_len);
    return r;
}

ssize_t hs_recv(int fd, void *buf, size_t len, int flags) {
#define CALL(f) recv_traced(fd, buf, len, f)
    BLOCKING_RECV(fd, flags, CALL);
#undef CALL
}

ssize_t hs_recvfrom(int fd, void *buf, size_t len, int flags, struct sockaddr *a, socklen_t *al) {
#define CALL(f) recvfrom_traced(fd, buf, len, f, a, al)
    BLOCKING_RECV(fd, flags, CALL);
#undef CALL
}

int hs_recvmmsg(int fd, struct mmsghdr *v, unsigned int n, int flags, struct timespec *tmo) {
    (void)tmo;
#define CALL(f) recvmmsg_traced(fd, v, n, f)
    BLOCKING_RECV(fd, flags, CALL);
#undef CALL
}

int hs_accept(int fd, struct sockaddr *a, socklen_t *al) {
    if (nonblocking(fd))
        return accept(fd, a, al);
    struct pollfd p = {.fd = fd, .events = POLLIN};
    tstate *t = hs__me();
    for (;;) {
        struct pollfd q = p;
        if (real_poll(&q, 1, 0) > 0)
            return accept(fd, a, al);
        sim_wait(t, &p, 1, NO_DEADLINE, NULL, 0);
    }
}

/* A datagram sent (counted for the runtime's settle); traced with its first ``len`` bytes at most. */
static void count_sent(int fd, ssize_t r, const void *b, size_t len) {
    if (r >= 0) {
        __atomic_add_fetch(&sent, 1, __ATOMIC_RELEASE);
        if (b)
            trace_frames("send", fd, b, (size_t)r < len ? r : (ssize_t)len);
    }
}

ssize_t hs_sendto(int fd, const void *b, size_t n, int fl, const struct sockaddr *a, socklen_t al) {
    ssize_t r = sendto(fd, b, n, fl, a, al);
    count_sent(fd, r, b, n);
    return r;
}

ssize_t hs_send(int fd, const void *b, size_t n, int fl) {
    ssize_t r = send(fd, b, n, fl);
    count_sent(fd, r, b, n);
    return r;
}

ssize_t hs_sendmsg(int fd, const struct msghdr *m, int fl) {
    ssize_t r = sendmsg(fd, m, fl);
    count_sent(fd, r, m->msg_iovlen ? m->msg_iov[0].iov_base : NULL, m->msg_iovlen ? m->msg_iov[0].iov_len : 0);
    return r;
}

int hs_sendmmsg(int fd, struct mmsghdr *v, unsigned int n, int fl) {
    int r = sendmmsg(fd, v, n, fl);
    for (int i = 0; i < r; i++)
        count_sent(fd, (ssize_t)v[i].msg_len, v[i].msg_hdr.msg_iov[0].iov_base, v[i].msg_hdr.msg_iov[0].iov_len);
    return r;
}
