/*
 * simcommon.h: what both sim-time shims share (simtime*.c, the mission's side; simchild.c, its children's side):
 * sim-time arithmetic, which clocks are sim time, select(2) as a wait on descriptors, the abstract unix address of
 * the mission's child server, and the line-by-line reading of their messages.
 *
 * Everything here is static inline: each shim compiles its own copy, and exports nothing from this file.
 */
#ifndef HARNESS_SIMCOMMON_H
#define HARNESS_SIMCOMMON_H

#include <poll.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#define NO_DEADLINE INT64_MAX
#define MAX_FDS 64

static inline int64_t ts_ns(const struct timespec *ts) { return (int64_t)ts->tv_sec * 1000000000LL + ts->tv_nsec; }

static inline void ns_ts(int64_t v, struct timespec *ts) {
    ts->tv_sec = v / 1000000000LL;
    ts->tv_nsec = v % 1000000000LL;
}

/* a + b, saturated at NO_DEADLINE. */
static inline int64_t add_ns(int64_t a, int64_t b) { return (b > 0 && a > NO_DEADLINE - b) ? NO_DEADLINE : a + b; }

/* The clocks that read sim time; the wall clocks read the run's epoch plus sim time; any other (CPU time) is real. */
static inline int is_sim_clock(clockid_t c) {
    return c == CLOCK_MONOTONIC || c == CLOCK_MONOTONIC_RAW || c == CLOCK_MONOTONIC_COARSE || c == CLOCK_BOOTTIME;
}

static inline int is_wall_clock(clockid_t c) {
    return c == CLOCK_REALTIME || c == CLOCK_REALTIME_COARSE || c == CLOCK_TAI;
}

/* select(2) with a timeout on the sim clock: `raw` (the real select) is tried with a zero timeout, and while nothing
 * is ready the caller's `wait` blocks on the sets' descriptors as pollfds (at most MAX_FDS) until one is ready or
 * sim time reaches `deadline` (it returns 1 when it timed out: one last try then answers). The sets are given back
 * to `raw` as the caller passed them before each try. */
typedef int (*raw_select_fn)(int nfds, fd_set *r, fd_set *w, fd_set *e, struct timeval *tv);
typedef int (*fds_wait_fn)(void *ctx, struct pollfd *p, int n, int64_t deadline);

static inline int select_on_sim(int nfds, fd_set *r, fd_set *w, fd_set *e, int64_t deadline, raw_select_fn raw,
                                fds_wait_fn wait, void *ctx) {
    struct timeval zero = {0, 0};
    fd_set r0, w0, e0;
    if (r) r0 = *r;
    if (w) w0 = *w;
    if (e) e0 = *e;
    struct pollfd p[MAX_FDS];
    int n = 0;
    for (int fd = 0; fd < nfds && n < MAX_FDS; fd++) {
        short evs = (short)((r && FD_ISSET(fd, &r0) ? POLLIN : 0) | (w && FD_ISSET(fd, &w0) ? POLLOUT : 0) |
                            (e && FD_ISSET(fd, &e0) ? POLLPRI : 0));
        if (evs) {
            p[n].fd = fd;
            p[n].events = evs;
            p[n++].revents = 0;
        }
    }
    for (;;) {
        if (r) *r = r0;
        if (w) *w = w0;
        if (e) *e = e0;
        struct timeval z = zero;
        int res = raw(nfds, r, w, e, &z);
        if (res != 0)
            return res;
        if (wait(ctx, p, n, deadline)) {
            if (r) *r = r0;
            if (w) *w = w0;
            if (e) *e = e0;
            z = zero;
            return raw(nfds, r, w, e, &z);
        }
    }
}

/* A blocking wait for a child (wait4 without WNOHANG) as a sim-time wait: `raw` (the real wait4) is tried with
 * WNOHANG; while no child has changed, the caller's `wait` blocks on the child's pidfd, or (any child, or no pidfd)
 * until a phase later (`now()` + 20 ms): the child runs meanwhile, and the waiter counts idle until it has exited. */
typedef pid_t (*raw_wait4_fn)(pid_t pid, int *status, int options, struct rusage *ru);

static inline pid_t wait4_on_sim(pid_t pid, int *status, int options, struct rusage *ru, raw_wait4_fn raw,
                                 fds_wait_fn wait, void *ctx, int64_t (*now)(void)) {
    int pfd = pid > 0 ? (int)syscall(SYS_pidfd_open, pid, 0) : -1;
    for (;;) {
        pid_t r = raw(pid, status, options | WNOHANG, ru);
        if (r != 0) { /* reaped (or an error): once, here */
            if (pfd >= 0)
                close(pfd);
            return r;
        }
        if (pfd >= 0) {
            struct pollfd p = {.fd = pfd, .events = POLLIN};
            wait(ctx, &p, 1, NO_DEADLINE);
        } else {
            wait(ctx, NULL, 0, add_ns(now(), 20000000LL)); /* any child: look again a phase later */
        }
    }
}

/* The abstract unix address `name` (the mission's child server) in `a`; its length, 0 when the name is too long. */
static inline socklen_t abstract_address(struct sockaddr_un *a, const char *name) {
    memset(a, 0, sizeof *a);
    a->sun_family = AF_UNIX;
    size_t len = strlen(name);
    if (len + 1 > sizeof a->sun_path)
        return 0;
    memcpy(a->sun_path + 1, name, len); /* abstract namespace: a leading NUL */
    return (socklen_t)(offsetof(struct sockaddr_un, sun_path) + 1 + len);
}

/* The line after `line` in a buffer of messages, one a line (NULL after the last). */
static inline char *next_line(char *line) {
    char *nl = strchr(line, '\n');
    return nl ? nl + 1 : NULL;
}

#endif
