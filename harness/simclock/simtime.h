/*
 * simtime.h: the mission's side of the sim-time shim, its private header (simtime.c has the overview).
 *
 * The shim is one shared object built from
 *   simtime.c           the state, the thread states, the wait and the gate's release; the threads it tracks
 *   simtime_clock.c     hooks: clocks, sleeps, condition variables, futexes, semaphores, timerfds
 *   simtime_io.c        hooks: poll/epoll/select, blocking receives and accept, sends
 *   simtime_children.c  child processes: the children's server, fork/spawn/wait
 *   simtime_control.c   the clock thread's side (hs_configure ... hs_describe, hs_snapshot), called through ctypes
 *   simtime_patch.c     the GOT patching (hs_patch, hs_patch_process, hs_become_child) and the hook tables
 * and simcommon.h, which simchild.c shares. It is compiled with -fvisibility=hidden: only what is marked HS_API
 * (the functions harness.simclock.native calls) is exported; everything else here is internal to the object.
 */
#ifndef HARNESS_SIMTIME_H
#define HARNESS_SIMTIME_H

#define _GNU_SOURCE
#include <dlfcn.h>
#include <elf.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <link.h>
#include <linux/futex.h>
#include <poll.h>
#include <pthread.h>
#include <semaphore.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/mman.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <sys/resource.h>
#include <spawn.h>
#include <stddef.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

#include "simcommon.h"

/* Everything declared from here on is internal to the shared object (but what HS_API marks). */
#pragma GCC visibility push(hidden)

/* The functions Python calls (ctypes): the only symbols the shared object exports. */
#define HS_API __attribute__((visibility("default")))

#define MAX_TIMERS 64

typedef struct tstate {
    struct tstate *next;
    int index; /* creation order: names the thread in a trace */
    pthread_t self;
    int evfd;            /* written to wake this thread */
    int tracked;         /* created by the library: counts in the phase's idle decision */
    int asks;            /* not MAVSDK's (whose input comes with its vehicle's MAVLink): pending asks for a phase */
    int waiting;         /* inside a wait */
    int released;        /* its wait was ended (by a wake, a deadline or its I/O): it runs */
    int pending;         /* its I/O or a wake came while the gate was closed: released at the next phase */
    int timed_out;
    int interrupted;     /* released for a signal (a timer of the runtime's): the call returns EINTR */
    int64_t deadline;    /* sim ns, NO_DEADLINE */
    const void *addr;    /* the condition variable or futex it waits on */
    int nfds;
    struct pollfd fds[MAX_FDS];
    pid_t pid;           /* a child process of the mission (simchild.c), not a thread: 0 for threads */
    int child_fd;        /* its connection (-1 until it says hello, and while it execs) */
    int pidfd;           /* readable when it has exited */
    pid_t parent;        /* the child of the mission that started it (0: the mission itself) */
    int child_exited;    /* a child of this child exited while it ran: its next wait ends at once */
    pid_t tid;           /* the kernel's id of the thread (diagnostics: which system call it is in) */
    char call[24];       /* the call it waits in, or last waited in (diagnostics) */
} tstate;

typedef struct {
    int fd;
    int64_t deadline;
    int64_t interval;
    int64_t now_at;  /* the sim time of the last "fire now" */
    int now_count;   /* how many in a row at that sim time */
} simtimer;

/* -- the state (simtime.c), shared by every part under `mu` ------------------------------------------ */

extern pthread_mutex_t mu;
extern pthread_cond_t changed; /* the clock thread waits on it */
extern uint64_t generation;
extern int64_t now_ns;
extern int64_t epoch_ns;
extern int gate_open;
extern int closed; /* the run is over: every wait ends */
extern uint64_t sent;
extern tstate *threads;
extern simtimer timers[MAX_TIMERS];
extern int thread_count;
extern FILE *trace; /* HARNESS_SIMTIME_TRACE: every release, for comparing two runs */
extern int active;  /* hs_configure ran: the hooks put their callers on sim time */
extern __thread int wall_thread; /* the harness's own threads (the clock thread): hooks pass through */
extern int want_fd; /* written when a wait outside MAVSDK's core became ready between phases */

/* Whether the calling thread's clock and waits are sim time (the process hooks pass through otherwise). */
static inline int on_sim(void) { return __atomic_load_n(&active, __ATOMIC_ACQUIRE) && !wall_thread; }

static inline int64_t sim_now(void) { return __atomic_load_n(&now_ns, __ATOMIC_ACQUIRE); }

#define TRACE(...)                                                                                        \
    do {                                                                                                  \
        if (trace) {                                                                                      \
            fprintf(trace, "%lld ", (long long)now_ns);                                                   \
            fprintf(trace, __VA_ARGS__);                                                                  \
            fputc('\n', trace);                                                                           \
        }                                                                                                 \
    } while (0)

/* -- the real functions ------------------------------------------------------------------------------ */

static inline int real_clock_gettime(clockid_t c, struct timespec *ts) { return clock_gettime(c, ts); }

static inline int real_poll(struct pollfd *f, nfds_t n, int ms) { return (int)syscall(SYS_poll, f, n, ms); }

static inline void wake_fd(int fd) {
    uint64_t one = 1;
    ssize_t r = write(fd, &one, sizeof one);
    (void)r;
}

/* Read an eventfd's count if it has one (never blocks: a timer's eventfd may be blocking). */
static inline void drain_fd(int fd) {
    struct pollfd p = {.fd = fd, .events = POLLIN};
    if (real_poll(&p, 1, 0) > 0) {
        uint64_t v;
        ssize_t r = read(fd, &v, sizeof v);
        (void)r;
    }
}

/* -- the core (simtime.c) ---------------------------------------------------------------------------- */

void hs__poke_locked(void);
void hs__release_locked(tstate *t, int timed_out);
int hs__busy_locked(void);
int hs__release_ready_locked(void);
tstate *hs__me(void);
int hs__sim_wait_in(tstate *t, const struct pollfd *fds, int nfds, int64_t deadline, const void *addr, int locked,
                    const char *call);
#define sim_wait(...) hs__sim_wait_in(__VA_ARGS__, __func__)

/* simtime_clock.c */
void hs__fire_due_timers_locked(void);

/* simtime_children.c */
void hs__close_child_fds_locked(tstate *t);
void hs__tell_child(tstate *t, char what);

/* -- the hooks: what a patched GOT entry calls instead of libc (simtime_patch.c's tables) ------------ */

int hs_pthread_create(pthread_t *th, const pthread_attr_t *attr, void *(*fn)(void *), void *arg);
int hs_foreign_pthread_create(pthread_t *th, const pthread_attr_t *attr, void *(*fn)(void *), void *arg);

int hs_clock_gettime(clockid_t c, struct timespec *ts);
int hs_gettimeofday(struct timeval *tv, void *tz);
time_t hs_time(time_t *out);
int hs_nanosleep(const struct timespec *req, struct timespec *rem);
int hs_clock_nanosleep(clockid_t c, int flags, const struct timespec *req, struct timespec *rem);
int hs_usleep(useconds_t us);
unsigned int hs_sleep(unsigned int s);
int hs_cond_init(pthread_cond_t *c, const pthread_condattr_t *a);
int hs_cond_destroy(pthread_cond_t *c);
int hs_cond_wait(pthread_cond_t *c, pthread_mutex_t *m);
int hs_cond_timedwait(pthread_cond_t *c, pthread_mutex_t *m, const struct timespec *abst);
int hs_cond_signal(pthread_cond_t *c);
int hs_cond_broadcast(pthread_cond_t *c);
int hs_timerfd_create(int clockid, int flags);
int hs_timerfd_settime(int fd, int flags, const struct itimerspec *nv, struct itimerspec *old);
int hs_close_fd(int fd);
long hs_syscall(long nr, long a1, long a2, long a3, long a4, long a5, long a6);
int hs_sem_clockwait(sem_t *s, clockid_t c, const struct timespec *abst);
int hs_sem_timedwait(sem_t *s, const struct timespec *abst);
int hs_sem_post(sem_t *s);

int hs_poll(struct pollfd *fds, nfds_t n, int ms);
int hs_epoll_wait(int ep, struct epoll_event *ev, int max, int ms);
int hs_select(int nfds, fd_set *r, fd_set *w, fd_set *e, struct timeval *tv);
ssize_t hs_recv(int fd, void *buf, size_t len, int flags);
ssize_t hs_recvfrom(int fd, void *buf, size_t len, int flags, struct sockaddr *a, socklen_t *al);
int hs_recvmmsg(int fd, struct mmsghdr *v, unsigned int n, int flags, struct timespec *tmo);
int hs_accept(int fd, struct sockaddr *a, socklen_t *al);
ssize_t hs_send(int fd, const void *b, size_t n, int fl);
ssize_t hs_sendto(int fd, const void *b, size_t n, int fl, const struct sockaddr *a, socklen_t al);
ssize_t hs_sendmsg(int fd, const struct msghdr *m, int fl);
int hs_sendmmsg(int fd, struct mmsghdr *v, unsigned int n, int fl);

pid_t hs_fork(void);
pid_t hs_vfork(void);
int hs_posix_spawn(pid_t *pid, const char *path, const posix_spawn_file_actions_t *fa, const posix_spawnattr_t *at,
                   char *const argv[], char *const envp[]);
int hs_posix_spawnp(pid_t *pid, const char *file, const posix_spawn_file_actions_t *fa, const posix_spawnattr_t *at,
                    char *const argv[], char *const envp[]);
pid_t hs_wait4(pid_t pid, int *status, int options, struct rusage *ru);
pid_t hs_waitpid(pid_t pid, int *status, int options);
pid_t hs_wait3(int *status, int options, struct rusage *ru);
pid_t hs_wait(int *status);

/* -- the API (exported) ------------------------------------------------------------------------------ */

/* One look at the shim's state, taken under `mu` in one call (hs_snapshot). */
typedef struct {
    uint64_t generation;    /* hs_generation */
    int64_t busy;           /* hs_busy: busy tracked threads and children */
    uint64_t sent;          /* hs_sent */
    int64_t next_deadline;  /* hs_next_deadline (NO_DEADLINE: none) */
    int64_t waits_for_io;   /* hs_waits_for_io */
    int64_t nwaiting;       /* the threads for which hs_thread_waiting is 1 (all of them, however many fit) */
} hs_state;

HS_API void hs_configure(int64_t epoch, int64_t t);
HS_API void hs_begin(int64_t t);
HS_API int hs_release_ready(void);
HS_API int hs_wait_library_idle(int64_t timeout_ns);
HS_API int hs_busy(void);
HS_API int hs_try_close(uint64_t g);
HS_API void hs_pause(void);
HS_API void hs_reopen(void);
HS_API int64_t hs_next_deadline(void);
HS_API int hs_waits_for_io(void);
HS_API int hs_thread_waiting(uint64_t self);
HS_API uint64_t hs_sent(void);
HS_API uint64_t hs_generation(void);
HS_API int hs_snapshot(hs_state *out, uint64_t *waiting, int cap);
HS_API void hs_poke(void);
HS_API void hs_wait_change(uint64_t g, int64_t timeout_ns);
HS_API void hs_close(void);
HS_API int hs_describe(char *out, int cap);
HS_API void hs_set_wall(int wall);
HS_API int hs_interrupt(uint64_t self);
HS_API int hs_want_fd(void);
HS_API int hs_children(const char *name);
HS_API int hs_patch_process(void);
HS_API int hs_patch(const char *target);
HS_API int hs_become_child(const char *path);

#pragma GCC visibility pop

#endif
