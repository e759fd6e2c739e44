/*
 * simchild.c: a child process of a mission in the mission's lockstep (issue 33).
 *
 * A program the mission starts (subprocess, asyncio, os.posix_spawn, multiprocessing's spawn and forkserver) runs
 * with this library in LD_PRELOAD and HARNESS_SIMTIME_PARENT naming the mission's child server (simtime.c,
 * hs_children). A child forked without exec (multiprocessing's fork) gets the same functions through its GOTs
 * (simtime.c, hs_become_child). Either way the whole process is one participant of the mission's phase 0:
 *  - it tells the mission "H pid" when it starts and learns the sim time ("T ns"); it is busy until it waits;
 *  - every clock read is sim time (CLOCK_MONOTONIC/BOOTTIME: sim time; CLOCK_REALTIME, gettimeofday, time: the
 *    run's epoch plus sim time); CPU clocks stay real;
 *  - every blocking call (sleeps, poll/select/epoll with a timeout or none, a blocking read, recv or accept that
 *    would block, waitpid) is a wait: when every thread of the process waits it sends "W deadline" (-1: none) and
 *    blocks; descriptors that become ready send "R" (the mission lets it run in a phase, never between two); the
 *    mission answers "G ns" when the process may run: a deadline at or before that time has passed, a ready
 *    descriptor is read;
 *  - a fork tells the mission "F pid" before it returns, so the new process counts from its first moment.
 * Everything real is called through libc's own symbols (dlsym on libc), never through this library's.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "simcommon.h"

static int client = -1;   /* the connection to the mission (-1: not a child of a mission: everything real) */
static pid_t client_pid;  /* the process that opened it (a fork needs its own) */
static int64_t now_ns;    /* sim time, from the mission */
static int64_t epoch_ns;
static pthread_mutex_t cmu = PTHREAD_MUTEX_INITIALIZER;
static int nthreads = 1;  /* threads of this process (pthread_create) */
static int nwaiting;      /* of those, inside a wait */
#define SLOTS 64
#define SLOT_FDS 8
static int used[SLOTS];          /* a waiting thread holds the slot */
static int64_t deadlines[SLOTS]; /* its deadline (NO_DEADLINE: none) */
static struct pollfd slot_fds[SLOTS][SLOT_FDS]; /* the descriptors it waits for: the mission polls them too */
static int slot_n[SLOTS];
static uint64_t go_gen;   /* "G" messages received */
static int said_wait;     /* "W" sent since the last "G" */
static int asked;         /* "R" sent since the last "G" */

/* -- libc's own functions ---------------------------------------------------------------------------- */

static void *libc_sym(const char *name) {
    static void *libc;
    if (!libc)
        libc = dlopen("libc.so.6", RTLD_NOW | RTLD_NOLOAD);
    return libc ? dlsym(libc, name) : NULL;
}

#define REAL(ret, name, ...)                                                                              \
    static ret (*real_##name)(__VA_ARGS__);                                                               \
    static void load_##name(void) {                                                                       \
        if (!real_##name)                                                                                 \
            real_##name = (ret(*)(__VA_ARGS__))libc_sym(#name);                                           \
    }

REAL(pid_t, fork, void)
REAL(int, posix_spawn, pid_t *, const char *, const void *, const void *, char *const[], char *const[])
REAL(int, posix_spawnp, pid_t *, const char *, const void *, const void *, char *const[], char *const[])
REAL(int, pthread_create, pthread_t *, const pthread_attr_t *, void *(*)(void *), void *)

static int raw_poll(struct pollfd *f, nfds_t n, int ms) { return (int)syscall(SYS_poll, f, n, ms); }
static ssize_t raw_read(int fd, void *b, size_t n) { return syscall(SYS_read, fd, b, n); }
static ssize_t raw_write(int fd, const void *b, size_t n) { return syscall(SYS_write, fd, b, n); }
static int raw_clock_gettime(clockid_t c, struct timespec *ts) { return (int)syscall(SYS_clock_gettime, c, ts); }

/* -- the connection ---------------------------------------------------------------------------------- */

static void say(const char *fmt, long long v) {
    char line[64];
    int n = snprintf(line, sizeof line, fmt, v);
    if (client >= 0 && raw_write(client, line, (size_t)n) < 0)
        client = -1; /* the mission is gone: real time from now on (the process is about to be stopped) */
}

/* Read what the mission sent (cmu held): "T ns" (the time), "G ns" (run). Blocks when `block`. */
static void hear_locked(int block) {
    char buf[512];
    for (;;) {
        if (!block) {
            struct pollfd p = {.fd = client, .events = POLLIN};
            if (raw_poll(&p, 1, 0) <= 0)
                return;
        }
        ssize_t n = raw_read(client, buf, sizeof buf - 1);
        if (n <= 0) {
            client = -1;
            return;
        }
        buf[n] = 0;
        for (char *line = buf; line && *line; line = next_line(line)) {
            if (line[0] == 'T' || line[0] == 'G') {
                long long v = atoll(line + 2);
                if (v > now_ns)
                    __atomic_store_n(&now_ns, v, __ATOMIC_RELEASE);
                if (line[0] == 'G') {
                    go_gen++;
                    said_wait = asked = 0;
                }
            }
        }
        if (buf[n - 1] == '\n')
            return;
        block = 1; /* a message cut in two: the rest follows */
    }
}

static int connect_parent(const char *name) {
    struct sockaddr_un a;
    socklen_t alen = abstract_address(&a, name);
    if (!alen)
        return -1;
    int fd = (int)syscall(SYS_socket, AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return -1;
    if (syscall(SYS_connect, fd, &a, alen) != 0) {
        close(fd);
        return -1;
    }
    return fd;
}

/* Join the mission named by HARNESS_SIMTIME_PARENT: say hello, learn the sim time. 1 when joined. */
int hs_child_start(void) {
    const char *name = getenv("HARNESS_SIMTIME_PARENT");
    const char *epoch = getenv("HARNESS_SIMTIME_EPOCH");
    if (!name || !*name || !epoch)
        return 0;
    pthread_mutex_lock(&cmu);
    if (client >= 0 && client_pid == getpid()) {
        pthread_mutex_unlock(&cmu);
        return 1; /* joined already (the constructor, then hs_become_child) */
    }
    if (client >= 0)
        close(client);
    client = connect_parent(name);
    client_pid = getpid();
    epoch_ns = atoll(epoch);
    nthreads = 1;
    nwaiting = 0;
    said_wait = asked = 0;
    for (int i = 0; i < SLOTS; i++) {
        used[i] = slot_n[i] = 0;
        deadlines[i] = NO_DEADLINE;
    }
    if (client >= 0) {
        say("H %lld\n", (long long)getpid());
        hear_locked(1); /* "T ns" */
    }
    pthread_mutex_unlock(&cmu);
    return client >= 0;
}

__attribute__((constructor)) static void start(void) {
    if (getenv("HARNESS_SIMTIME_PRELOADED"))
        hs_child_start();
}

static int on(void) { return __atomic_load_n(&client, __ATOMIC_ACQUIRE) >= 0; }

/* -- the wait ---------------------------------------------------------------------------------------- */

static int64_t sim_now(void) { return __atomic_load_n(&now_ns, __ATOMIC_ACQUIRE); }

static int64_t min_deadline_locked(void) {
    int64_t d = NO_DEADLINE;
    for (int i = 0; i < SLOTS; i++)
        d = used[i] && deadlines[i] < d ? deadlines[i] : d;
    return d;
}

/* "W deadline call fd:events …": the mission takes a copy of each descriptor (pidfd_getfd) and looks at them
 * before it ends a phase, as it does for its own threads' waits: what another participant wrote to it in this
 * phase runs this process in this phase, whatever the machine's pace. */
static void say_wait_locked(const char *call) {
    char line[1024];
    int64_t d = min_deadline_locked();
    int n = snprintf(line, sizeof line, "W %lld %s", d == NO_DEADLINE ? -1LL : (long long)d, call);
    for (int i = 0; i < SLOTS; i++) {
        for (int j = 0; used[i] && j < slot_n[i] && n < (int)sizeof line - 32; j++)
            n += snprintf(line + n, sizeof line - (size_t)n, " %d:%d", slot_fds[i][j].fd, slot_fds[i][j].events);
    }
    n += snprintf(line + n, sizeof line - (size_t)n, "\n");
    if (client >= 0 && raw_write(client, line, (size_t)n) < 0)
        client = -1;
}

static int ready(struct pollfd *fds, int n) {
    if (n == 0)
        return 0;
    struct pollfd p[MAX_FDS];
    memcpy(p, fds, (size_t)n * sizeof *p);
    return raw_poll(p, (nfds_t)n, 0) > 0;
}

/* Block (idle for the mission) until `fds` are ready in a phase or sim time reaches `deadline` (or, `on_go`, until
 * the mission lets the process run at all: a child of it exited). 1: timed out. */
static int child_wait_in(struct pollfd *fds, int n, int64_t deadline, int on_go, const char *call) {
    if (n > MAX_FDS)
        n = MAX_FDS;
    pthread_mutex_lock(&cmu);
    nwaiting++;
    int slot = -1;
    for (int i = 0; i < SLOTS && slot < 0; i++)
        slot = used[i] ? -1 : i;
    if (slot >= 0) {
        used[slot] = 1;
        deadlines[slot] = deadline;
        slot_n[slot] = n < SLOT_FDS ? n : SLOT_FDS;
        if (slot_n[slot])
            memcpy(slot_fds[slot], fds, (size_t)slot_n[slot] * sizeof *fds);
    }
    int timed_out = 0;
    for (;;) {
        if (client < 0)
            break;
        if (deadline != NO_DEADLINE && sim_now() >= deadline) {
            timed_out = 1;
            break;
        }
        if (said_wait == 0 && ready(fds, n))
            break; /* ready while the process still runs in this phase */
        if (nwaiting >= nthreads && !said_wait) {
            say_wait_locked(call);
            said_wait = 1;
        }
        uint64_t gen = go_gen;
        struct pollfd p[MAX_FDS + 1];
        int k = 0;
        if (!asked) {
            memcpy(p, fds, (size_t)n * sizeof *p);
            k = n;
        }
        p[k].fd = client;
        p[k].events = POLLIN;
        p[k].revents = 0;
        pthread_mutex_unlock(&cmu);
        raw_poll(p, (nfds_t)k + 1, -1);
        pthread_mutex_lock(&cmu);
        if (client < 0)
            break;
        if (p[k].revents)
            hear_locked(0);
        if (go_gen != gen) {
            if (deadline != NO_DEADLINE && sim_now() >= deadline) {
                timed_out = 1;
                break;
            }
            if (ready(fds, n) || on_go)
                break;
            continue; /* the mission let the process run for another thread's sake: wait again */
        }
        if (!asked && said_wait && ready(fds, n)) {
            say("R %lld\n", 0);
            asked = 1;
        }
    }
    nwaiting--;
    if (slot >= 0)
        used[slot] = 0;
    pthread_mutex_unlock(&cmu);
    return timed_out;
}

#define child_wait(fds, n, deadline) child_wait_in(fds, n, deadline, 0, __func__)

static int64_t after(int64_t ns) { return add_ns(sim_now(), ns); }
static int64_t ms_deadline(int ms) { return ms < 0 ? NO_DEADLINE : after((int64_t)ms * 1000000LL); }

/* -- the clock --------------------------------------------------------------------------------------- */

int clock_gettime(clockid_t c, struct timespec *ts) {
    if (!on() || !(is_sim_clock(c) || is_wall_clock(c)))
        return raw_clock_gettime(c, ts);
    ns_ts(is_sim_clock(c) ? sim_now() : epoch_ns + sim_now(), ts);
    return 0;
}

int gettimeofday(struct timeval *tv, void *tz) {
    (void)tz;
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    if (tv) {
        tv->tv_sec = ts.tv_sec;
        tv->tv_usec = ts.tv_nsec / 1000;
    }
    return 0;
}

time_t time(time_t *out) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    if (out)
        *out = ts.tv_sec;
    return ts.tv_sec;
}

/* -- sleeps ------------------------------------------------------------------------------------------ */

int clock_nanosleep(clockid_t c, int flags, const struct timespec *req, struct timespec *rem) {
    if (!on() || !(is_sim_clock(c) || is_wall_clock(c)))
        return (int)syscall(SYS_clock_nanosleep, c, flags, req, rem) == 0 ? 0 : errno;
    int64_t deadline;
    if (flags & TIMER_ABSTIME)
        deadline = ts_ns(req) - (is_wall_clock(c) ? epoch_ns : 0);
    else
        deadline = after(ts_ns(req));
    if (rem && !(flags & TIMER_ABSTIME))
        rem->tv_sec = rem->tv_nsec = 0;
    if (deadline > sim_now())
        child_wait(NULL, 0, deadline);
    return 0;
}

int nanosleep(const struct timespec *req, struct timespec *rem) {
    return clock_nanosleep(CLOCK_MONOTONIC, 0, req, rem) == 0 ? 0 : -1;
}

int usleep(useconds_t us) {
    struct timespec ts = {us / 1000000, (long)(us % 1000000) * 1000};
    return nanosleep(&ts, NULL);
}

unsigned int sleep(unsigned int s) {
    struct timespec ts = {s, 0};
    nanosleep(&ts, NULL);
    return 0;
}

/* -- waits on descriptors ---------------------------------------------------------------------------- */

int poll(struct pollfd *fds, nfds_t n, int ms) {
    if (!on() || ms == 0)
        return raw_poll(fds, n, ms);
    int64_t deadline = ms_deadline(ms);
    for (;;) {
        int r = raw_poll(fds, n, 0);
        if (r != 0)
            return r;
        if (child_wait(fds, (int)n, deadline))
            return raw_poll(fds, n, 0);
    }
}

int ppoll(struct pollfd *fds, nfds_t n, const struct timespec *tmo, const sigset_t *mask) {
    if (!on() || (tmo && ts_ns(tmo) == 0))
        return (int)syscall(SYS_ppoll, fds, n, tmo, mask, 8);
    return poll(fds, n, tmo ? (int)(ts_ns(tmo) / 1000000) : -1);
}

int epoll_wait(int ep, struct epoll_event *ev, int max, int ms) {
    if (!on() || ms == 0)
        return (int)syscall(SYS_epoll_wait, ep, ev, max, ms);
    int64_t deadline = ms_deadline(ms);
    struct pollfd p = {.fd = ep, .events = POLLIN};
    for (;;) {
        int r = (int)syscall(SYS_epoll_wait, ep, ev, max, 0);
        if (r != 0)
            return r;
        if (child_wait(&p, 1, deadline))
            return (int)syscall(SYS_epoll_wait, ep, ev, max, 0);
    }
}

int epoll_pwait(int ep, struct epoll_event *ev, int max, int ms, const sigset_t *mask) {
    (void)mask;
    return epoll_wait(ep, ev, max, ms);
}

static int raw_select(int nfds, fd_set *r, fd_set *w, fd_set *e, struct timeval *tv) {
    return (int)syscall(SYS_select, nfds, r, w, e, tv);
}

static int select_wait(void *ctx, struct pollfd *p, int n, int64_t deadline) {
    (void)ctx;
    return child_wait_in(p, n, deadline, 0, "select");
}

int select(int nfds, fd_set *r, fd_set *w, fd_set *e, struct timeval *tv) {
    if (!on() || (tv && tv->tv_sec == 0 && tv->tv_usec == 0))
        return raw_select(nfds, r, w, e, tv);
    int64_t deadline = tv ? after((int64_t)tv->tv_sec * 1000000000LL + (int64_t)tv->tv_usec * 1000) : NO_DEADLINE;
    return select_on_sim(nfds, r, w, e, deadline, raw_select, select_wait, NULL);
}

/* A blocking read, receive or accept that would block is a wait on its descriptor (a pipe the process reads until
 * its parent closes it, multiprocessing's resource tracker). */
static int would_block(int fd, const char *call) {
    if (!on() || (fcntl(fd, F_GETFL) & O_NONBLOCK))
        return 0;
    struct pollfd p = {.fd = fd, .events = POLLIN};
    if (raw_poll(&p, 1, 0) != 0)
        return 0;
    child_wait_in(&p, 1, NO_DEADLINE, 0, call);
    return 1;
}

ssize_t read(int fd, void *b, size_t n) {
    while (would_block(fd, "read")) {
    }
    return raw_read(fd, b, n);
}

ssize_t recv(int fd, void *b, size_t n, int flags) {
    while (!(flags & MSG_DONTWAIT) && would_block(fd, "recv")) {
    }
    return syscall(SYS_recvfrom, fd, b, n, flags, NULL, NULL);
}

ssize_t recvfrom(int fd, void *b, size_t n, int flags, struct sockaddr *a, socklen_t *al) {
    while (!(flags & MSG_DONTWAIT) && would_block(fd, "recvfrom")) {
    }
    return syscall(SYS_recvfrom, fd, b, n, flags, a, al);
}

int accept(int fd, struct sockaddr *a, socklen_t *al) {
    while (would_block(fd, "accept")) {
    }
    return (int)syscall(SYS_accept, fd, a, al);
}

/* A blocking wait for a child: a wait on the child's pidfd (any child: polled at each phase). */
static pid_t raw_wait4(pid_t pid, int *status, int options, struct rusage *ru) {
    return (pid_t)syscall(SYS_wait4, pid, status, options, ru);
}

static int wait4_wait(void *ctx, struct pollfd *p, int n, int64_t deadline) {
    (void)ctx;
    return child_wait_in(p, n, deadline, 1, "wait4"); /* any "G" may be a child's exit: wait4 looks again */
}

pid_t wait4(pid_t pid, int *status, int options, struct rusage *ru) {
    if (on() && !(options & WNOHANG))
        return wait4_on_sim(pid, status, options, ru, raw_wait4, wait4_wait, NULL, sim_now);
    return raw_wait4(pid, status, options, ru);
}

pid_t waitpid(pid_t pid, int *status, int options) { return wait4(pid, status, options, NULL); }

/* Shells wait with these (dash: wait3): inside libc they call wait4 directly, past this library. */
pid_t wait3(int *status, int options, struct rusage *ru) { return wait4(-1, status, options, ru); }

pid_t wait(int *status) { return wait4(-1, status, 0, NULL); }

/* -- processes and threads --------------------------------------------------------------------------- */

pid_t fork(void) {
    load_fork();
    pid_t pid = real_fork();
    if (pid > 0) {
        pthread_mutex_lock(&cmu);
        say("F %lld\n", (long long)pid); /* counted from now on, before this process can wait */
        pthread_mutex_unlock(&cmu);
    } else if (pid == 0 && client >= 0) {
        hs_child_start(); /* its own connection */
    }
    return pid;
}

pid_t vfork(void) { return fork(); }

/* A spawned child counts from now on, before this process can wait for it. */
static int spawned(int r, const pid_t *pid) {
    if (r == 0 && pid && client >= 0) {
        pthread_mutex_lock(&cmu);
        say("F %lld\n", (long long)*pid);
        pthread_mutex_unlock(&cmu);
    }
    return r;
}

int posix_spawn(pid_t *pid, const char *path, const void *fa, const void *at, char *const argv[], char *const envp[]) {
    load_posix_spawn();
    return spawned(real_posix_spawn(pid, path, fa, at, argv, envp), pid);
}

int posix_spawnp(pid_t *pid, const char *file, const void *fa, const void *at, char *const argv[], char *const envp[]) {
    load_posix_spawnp();
    return spawned(real_posix_spawnp(pid, file, fa, at, argv, envp), pid);
}

typedef struct {
    void *(*fn)(void *);
    void *arg;
} start_args;

static void thread_gone(void *p) {
    (void)p;
    pthread_mutex_lock(&cmu);
    nthreads--;
    pthread_mutex_unlock(&cmu);
}

static pthread_key_t gone_key;
static pthread_once_t gone_once = PTHREAD_ONCE_INIT;
static void make_gone_key(void) { pthread_key_create(&gone_key, thread_gone); }

static void *trampoline(void *p) {
    start_args s = *(start_args *)p;
    free(p);
    pthread_setspecific(gone_key, (void *)1);
    return s.fn(s.arg);
}

int pthread_create(pthread_t *th, const pthread_attr_t *attr, void *(*fn)(void *), void *arg) {
    load_pthread_create();
    if (!on())
        return real_pthread_create(th, attr, fn, arg);
    pthread_once(&gone_once, make_gone_key);
    start_args *s = malloc(sizeof *s);
    if (!s)
        return EAGAIN;
    s->fn = fn;
    s->arg = arg;
    pthread_mutex_lock(&cmu);
    nthreads++; /* busy from now on */
    pthread_mutex_unlock(&cmu);
    int r = real_pthread_create(th, attr, trampoline, s);
    if (r != 0) {
        thread_gone(NULL);
        free(s);
    }
    return r;
}
