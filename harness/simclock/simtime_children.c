/*
 * simtime_children.c: child processes of the mission in its lockstep (see simtime.c; their side is simchild.c).
 *
 * A process the mission starts (fork, vfork, posix_spawn) counts in the idle decision from its first moment, as a
 * tstate with a pid; the children's server (a thread on the wall clock) reads what each child says ("H" hello,
 * "F" it forked, "W" it waits, "R" a descriptor it waits for is ready) and notices its exit (a pidfd). A wait for
 * a child is a sim-time wait on its pidfd.
 */
#include "simtime.h"

#define MAX_CHILDREN 256
static int server_fd = -1;        /* listening: children connect here (an abstract unix socket) */
static int children_started;      /* the server thread runs */
static char static_warned[4096];  /* programs already reported as statically linked */

/* Send a child "G ns" (run) or "T ns" (the time). */
void hs__tell_child(tstate *t, char what) {
    if (t->child_fd < 0)
        return;
    char line[48];
    int n = snprintf(line, sizeof line, "%c %lld\n", what, (long long)now_ns);
    ssize_t r = send(t->child_fd, line, (size_t)n, MSG_NOSIGNAL);
    (void)r;
}

/* A child process, busy from now on (mu held): counted in the idle decision until it exits. */
static tstate *add_child_locked(pid_t pid) {
    for (tstate *t = threads; t; t = t->next) {
        if (t->pid == pid)
            return t;
    }
    tstate *t = calloc(1, sizeof *t);
    if (!t)
        abort();
    t->evfd = -1;
    t->child_fd = -1;
    t->tracked = 1;
    t->asks = 1;
    t->deadline = NO_DEADLINE;
    t->pid = pid;
    t->pidfd = (int)syscall(SYS_pidfd_open, pid, 0);
    t->index = ++thread_count;
    TRACE("child %d pid=%d", t->index, (int)pid);
    t->next = threads;
    threads = t;
    return t;
}

/* Close the mission's copies of a child's descriptors. */
void hs__close_child_fds_locked(tstate *t) {
    for (int i = 0; i < t->nfds; i++)
        close(t->fds[i].fd);
    t->nfds = 0;
}

/* A child waits for its descriptors " fd:events …": copies of them (pidfd_getfd) go into its wait, so that the clock
 * thread releases it when one is ready before it ends a phase (hs__release_ready_locked), as for a thread of its own.
 * Without pidfd_getfd (an old kernel, a sandbox) the child's own "R" is all there is. */
static void take_child_fds_locked(tstate *t, const char *rest) {
    hs__close_child_fds_locked(t);
    while (t->pidfd >= 0 && rest && *rest == ' ' && t->nfds < MAX_FDS) {
        int fd = atoi(rest + 1);
        const char *colon = strchr(rest + 1, ':');
        if (!colon)
            break;
        short events = (short)atoi(colon + 1);
        rest = strchr(colon, ' ');
        if (!(events & (POLLIN | POLLPRI)))
            continue; /* a copy of a write end would keep its reader from seeing the end of the stream */
        int copy = (int)syscall(SYS_pidfd_getfd, t->pidfd, fd, 0);
        if (copy >= 0) {
            fcntl(copy, F_SETFD, FD_CLOEXEC);
            t->fds[t->nfds].fd = copy;
            t->fds[t->nfds].events = events;
            t->fds[t->nfds++].revents = 0;
        }
    }
}

static void drop_child_locked(tstate *t) {
    for (tstate **pp = &threads; *pp; pp = &(*pp)->next) {
        if (*pp == t) {
            *pp = t->next;
            break;
        }
    }
    TRACE("child %d exited", t->index);
    hs__close_child_fds_locked(t);
    /* Its parent, if a child of the mission too, runs now (SIGCHLD is on its way to it: when the parent takes the
     * "G", the signal has been handled and whatever its handler wrote is ready): in this phase, at any pace. A
     * parent that is running still ends its next wait at once (a shell's wait3 for any child has no descriptor
     * that could say so: its "W" may come after the exit). */
    for (tstate *p = threads; t->parent && p; p = p->next) {
        if (p->pid != t->parent)
            continue;
        if (p->waiting && !p->released)
            hs__release_locked(p, 0);
        else
            p->child_exited = 1;
    }
    if (t->child_fd >= 0)
        close(t->child_fd);
    if (t->pidfd >= 0)
        close(t->pidfd);
    free(t);
    hs__poke_locked();
}

/* One message of a child (mu held): "H pid" hello, "F pid" it forked, "W ns" it waits (-1: no deadline), "R" a
 * descriptor it waits for is ready. */
static void child_says_locked(tstate *t, int fd, const char *line) {
    long long v = atoll(line + 2);
    switch (line[0]) {
    case 'H': {
        tstate *c = add_child_locked((pid_t)v);
        if (c->child_fd >= 0 && c->child_fd != fd)
            close(c->child_fd);
        c->child_fd = fd;
        c->waiting = c->released = c->pending = 0;
        hs__tell_child(c, 'T');
        break;
    }
    case 'F':
        add_child_locked((pid_t)v)->parent = t ? t->pid : 0;
        break;
    case 'W':
        if (!t)
            break;
        t->waiting = 1;
        t->released = t->pending = t->timed_out = 0;
        t->deadline = v < 0 ? NO_DEADLINE : v;
        const char *call = strchr(line + 2, ' ');
        if (call) {
            size_t k = strcspn(call + 1, " \n");
            snprintf(t->call, sizeof t->call, "%.*s", (int)(k < sizeof t->call ? k : sizeof t->call - 1), call + 1);
            take_child_fds_locked(t, call + 1 + k);
        }
        if (t->child_exited)
            hs__release_locked(t, 0); /* a child of it exited while it ran */
        else if (gate_open && t->deadline <= now_ns)
            hs__release_locked(t, 1);
        t->child_exited = 0;
        hs__poke_locked();
        break;
    case 'R':
        if (t && t->waiting && !t->released)
            hs__release_locked(t, 0);
        if (t && t->pending)
            hs__poke_locked();
        break;
    }
}

/* Whether the program of process `pid` is statically linked (no PT_INTERP): nothing can be interposed in it. */
static int is_static(pid_t pid, char *exe, size_t cap) {
    char path[64];
    snprintf(path, sizeof path, "/proc/%d/exe", (int)pid);
    ssize_t n = readlink(path, exe, cap - 1);
    if (n <= 0)
        return 0;
    exe[n] = 0;
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return 0;
    ElfW(Ehdr) eh;
    int stat = 0;
    if (pread(fd, &eh, sizeof eh, 0) == (ssize_t)sizeof eh && memcmp(eh.e_ident, ELFMAG, SELFMAG) == 0) {
        stat = 1;
        for (int i = 0; i < eh.e_phnum; i++) {
            ElfW(Phdr) ph;
            if (pread(fd, &ph, sizeof ph, (off_t)(eh.e_phoff + (ElfW(Off))i * eh.e_phentsize)) != (ssize_t)sizeof ph)
                break;
            if (ph.p_type == PT_INTERP) {
                stat = 0;
                break;
            }
        }
    }
    close(fd);
    return stat;
}

/* The children's server (a thread of its own, on the wall clock): new connections, their messages, their exits. */
static void *serve_children(void *arg) {
    (void)arg;
    wall_thread = 1;
    char buf[4096];
    for (;;) {
        struct pollfd p[2 * MAX_CHILDREN + 1];
        tstate *who[2 * MAX_CHILDREN + 1];
        int n = 0;
        p[n].fd = server_fd;
        p[n].events = POLLIN;
        who[n++] = NULL;
        pthread_mutex_lock(&mu);
        for (tstate *t = threads; t && n < 2 * MAX_CHILDREN - 1; t = t->next) {
            if (!t->pid)
                continue;
            if (t->child_fd >= 0) {
                p[n].fd = t->child_fd;
                p[n].events = POLLIN;
                who[n++] = t;
            }
            if (t->pidfd >= 0) {
                p[n].fd = t->pidfd;
                p[n].events = POLLIN;
                who[n++] = t;
            }
        }
        pthread_mutex_unlock(&mu);
        int r = real_poll(p, (nfds_t)n, 200);
        pthread_mutex_lock(&mu);
        if (r == 0) { /* a quiet moment: a child that never said hello may be a program nothing can interpose */
            for (tstate *t = threads; t; t = t->next) {
                char exe[1024];
                if (t->pid && t->child_fd < 0 && !t->waiting && is_static(t->pid, exe, sizeof exe) &&
                    !strstr(static_warned, exe) && strlen(static_warned) + strlen(exe) + 2 < sizeof static_warned) {
                    strcat(static_warned, exe);
                    strcat(static_warned, "\n");
                    fprintf(stderr,
                            "harness mission: %s is statically linked: nothing can put it on the sim clock; it runs on "
                            "the wall clock, outside the phases\n",
                            exe);
                }
                if (t->pid && t->child_fd < 0 && !t->waiting && t->tracked && strstr(static_warned, exe) &&
                    is_static(t->pid, exe, sizeof exe)) {
                    t->tracked = 0; /* no longer waited for: a server (mavsdk_server) would hold phase 0 for good */
                    hs__poke_locked();
                }
            }
        }
        for (int i = 0; i < n && r > 0; i++) {
            if (!p[i].revents)
                continue;
            tstate *t = who[i];
            if (!t) {
                int fd = accept4(server_fd, NULL, NULL, SOCK_CLOEXEC);
                if (fd >= 0) { /* its hello comes next, read at once: it waits for the answer */
                    ssize_t k = recv(fd, buf, sizeof buf - 1, 0);
                    if (k > 0) {
                        buf[k] = 0;
                        child_says_locked(NULL, fd, buf);
                    } else {
                        close(fd);
                    }
                }
                continue;
            }
            if (p[i].fd == t->pidfd) { /* exited */
                drop_child_locked(t);
                break; /* the list changed: look again */
            }
            if (p[i].fd != t->child_fd)
                continue; /* a connection it replaced (closed when the new one said hello) */
            ssize_t k = recv(t->child_fd, buf, sizeof buf - 1, MSG_DONTWAIT);
            if (k < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
                continue;
            if (k <= 0) { /* it exec'd or is exiting: busy until it says hello again or its pidfd says it ended */
                close(t->child_fd);
                t->child_fd = -1;
                t->waiting = t->released = t->pending = 0;
                hs__close_child_fds_locked(t);
                continue;
            }
            buf[k] = 0;
            for (char *line = buf; line && *line; line = next_line(line))
                child_says_locked(t, t->child_fd, line);
        }
        pthread_mutex_unlock(&mu);
    }
    return NULL;
}

/* Start the children's server at the abstract unix address `name`; 1 when it listens. Idempotent. */
int hs_children(const char *name) {
    if (children_started)
        return 1;
    struct sockaddr_un a;
    socklen_t alen = abstract_address(&a, name);
    if (!alen)
        return 0;
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return 0;
    if (bind(fd, (struct sockaddr *)&a, alen) != 0 || listen(fd, 64) != 0) {
        close(fd);
        return 0;
    }
    server_fd = fd;
    pthread_t th;
    if (pthread_create(&th, NULL, serve_children, NULL) != 0)
        return 0;
    pthread_detach(th);
    children_started = 1;
    return 1;
}

/* A process started by the mission counts from its first moment (fork, posix_spawn). */
static void started_child(pid_t pid) {
    if (pid <= 0 || !children_started || !on_sim())
        return;
    pthread_mutex_lock(&mu);
    add_child_locked(pid);
    pthread_mutex_unlock(&mu);
}

pid_t hs_fork(void) {
    pid_t pid = fork();
    if (pid > 0)
        started_child(pid);
    return pid;
}

/* vfork's child borrows the caller's stack: a wrapper cannot return in it. A fork does the same for a child that
 * execs at once (subprocess). */
pid_t hs_vfork(void) { return hs_fork(); }

int hs_posix_spawn(pid_t *pid, const char *path, const posix_spawn_file_actions_t *fa,
                          const posix_spawnattr_t *at, char *const argv[], char *const envp[]) {
    int r = posix_spawn(pid, path, fa, at, argv, envp);
    if (r == 0 && pid)
        started_child(*pid);
    return r;
}

int hs_posix_spawnp(pid_t *pid, const char *file, const posix_spawn_file_actions_t *fa,
                           const posix_spawnattr_t *at, char *const argv[], char *const envp[]) {
    int r = posix_spawnp(pid, file, fa, at, argv, envp);
    if (r == 0 && pid)
        started_child(*pid);
    return r;
}

static int wait4_wait(void *t, struct pollfd *p, int n, int64_t deadline) {
    return hs__sim_wait_in(t, p, n, deadline, NULL, 0, "wait4");
}

/* A blocking wait for a child (subprocess's Popen.wait, asyncio's child watcher) is a sim-time wait on the child's
 * pidfd: the child runs meanwhile, and the waiter counts idle until the child has exited. */
pid_t hs_wait4(pid_t pid, int *status, int options, struct rusage *ru) {
    if (on_sim() && !(options & WNOHANG))
        return wait4_on_sim(pid, status, options, ru, wait4, wait4_wait, hs__me(), sim_now);
    return wait4(pid, status, options, ru);
}

pid_t hs_waitpid(pid_t pid, int *status, int options) { return hs_wait4(pid, status, options, NULL); }

/* os.wait3 and os.wait: inside libc they call wait4 directly, past the GOT. */
pid_t hs_wait3(int *status, int options, struct rusage *ru) { return hs_wait4(-1, status, options, ru); }

pid_t hs_wait(int *status) { return hs_wait4(-1, status, 0, NULL); }
