/*
 * simtime_patch.c: the GOT patching (see simtime.c): which calls of which loaded object come to the shim's hooks
 * (the tables), rewriting an object's GOT entries, the whole process (and libraries loaded later, dlopen/dlsym),
 * and a process forked without exec switching to the children's side (simchild.c).
 */
#include "simtime.h"

static int patched_count;
static pthread_mutex_t patch_mu = PTHREAD_MUTEX_INITIALIZER;
static void *process_hook_for(const char *name);
static int patch_process_locked(void);


/* A library loaded later (an extension module, ctypes.CDLL) is put on sim time too. */
static void *hs_dlopen(const char *file, int mode) {
    void *h = dlopen(file, mode);
    if (h && __atomic_load_n(&active, __ATOMIC_ACQUIRE)) {
        pthread_mutex_lock(&patch_mu);
        patch_process_locked();
        pthread_mutex_unlock(&patch_mu);
    }
    return h;
}

/* ctypes looks functions up by name: a C function called through it (libc's usleep) is the hook. */
static void *hs_dlsym(void *h, const char *name) {
    void *r = dlsym(h, name);
    if (r && name && __atomic_load_n(&active, __ATOMIC_ACQUIRE)) {
        void *hk = process_hook_for(name);
        if (hk)
            return hk;
    }
    return r;
}

typedef struct {
    const char *name;
    void *fn;
} hook;

static const hook hooks[] = {
    {"clock_gettime", (void *)hs_clock_gettime},
    {"gettimeofday", (void *)hs_gettimeofday},
    {"time", (void *)hs_time},
    {"nanosleep", (void *)hs_nanosleep},
    {"pthread_cond_init", (void *)hs_cond_init},
    {"pthread_cond_destroy", (void *)hs_cond_destroy},
    {"pthread_cond_wait", (void *)hs_cond_wait},
    {"pthread_cond_timedwait", (void *)hs_cond_timedwait},
    {"pthread_cond_signal", (void *)hs_cond_signal},
    {"pthread_cond_broadcast", (void *)hs_cond_broadcast},
    {"poll", (void *)hs_poll},
    {"epoll_wait", (void *)hs_epoll_wait},
    {"select", (void *)hs_select},
    {"recv", (void *)hs_recv},
    {"recvfrom", (void *)hs_recvfrom},
    {"recvmmsg", (void *)hs_recvmmsg},
    {"accept", (void *)hs_accept},
    {"send", (void *)hs_send},
    {"sendto", (void *)hs_sendto},
    {"sendmsg", (void *)hs_sendmsg},
    {"sendmmsg", (void *)hs_sendmmsg},
    {"timerfd_create", (void *)hs_timerfd_create},
    {"timerfd_settime", (void *)hs_timerfd_settime},
    {"close", (void *)hs_close_fd},
    {"syscall", (void *)hs_syscall},
    {"pthread_create", (void *)hs_pthread_create},
};

/* The interpreter (libpython and its own extension modules): only its timed lock waits, which no Python-level
 * patch reaches, and the loader. Its clock reads stay real: the Python-level patches (patch.py) own the
 * interpreter's time API, and the GIL's switch interval (a pthread_cond_timedwait on a deadline it reads from
 * the real clock) must stay on the wall clock: which thread holds the GIL never moves sim time. */
static const hook interp_hooks[] = {
    {"fork", (void *)hs_fork},
    {"vfork", (void *)hs_vfork},
    {"posix_spawn", (void *)hs_posix_spawn},
    {"posix_spawnp", (void *)hs_posix_spawnp},
    {"wait4", (void *)hs_wait4},
    {"waitpid", (void *)hs_waitpid},
    {"wait3", (void *)hs_wait3},
    {"wait", (void *)hs_wait},
    {"sem_clockwait", (void *)hs_sem_clockwait},
    {"sem_timedwait", (void *)hs_sem_timedwait},
    {"sem_post", (void *)hs_sem_post},
    {"dlopen", (void *)hs_dlopen},
    {"dlsym", (void *)hs_dlsym},
};

/* Every other library of the process (C extensions and what they load: libzmq, ...), and C functions looked up
 * by name (ctypes): clock reads, sleeps, timed waits on descriptors and semaphores. */
static const hook foreign_hooks[] = {
    {"clock_gettime", (void *)hs_clock_gettime},
    {"gettimeofday", (void *)hs_gettimeofday},
    {"time", (void *)hs_time},
    {"nanosleep", (void *)hs_nanosleep},
    {"clock_nanosleep", (void *)hs_clock_nanosleep},
    {"usleep", (void *)hs_usleep},
    {"sleep", (void *)hs_sleep},
    {"poll", (void *)hs_poll},
    {"epoll_wait", (void *)hs_epoll_wait},
    {"select", (void *)hs_select},
    {"sem_clockwait", (void *)hs_sem_clockwait},
    {"sem_timedwait", (void *)hs_sem_timedwait},
    {"sem_post", (void *)hs_sem_post},
    {"dlopen", (void *)hs_dlopen},
    {"dlsym", (void *)hs_dlsym},
    {"pthread_create", (void *)hs_foreign_pthread_create},
};

#define NHOOKS(table) (sizeof table / sizeof table[0])

static void *find_hook(const hook *table, size_t n, const char *name) {
    for (size_t i = 0; i < n; i++) {
        if (strcmp(table[i].name, name) == 0)
            return table[i].fn;
    }
    return NULL;
}

static void *process_hook_for(const char *name) {
    if (strcmp(name, "dlopen") == 0 || strcmp(name, "dlsym") == 0 || strcmp(name, "pthread_create") == 0)
        return NULL;
    return find_hook(foreign_hooks, NHOOKS(foreign_hooks), name);
}

/* ld.so relocates the pointers of a loaded object's dynamic section on most systems; not on all. */
static uintptr_t dyn_ptr(ElfW(Addr) base, ElfW(Addr) p) { return p < base ? base + p : p; }

static void patch_rela(ElfW(Addr) base, const ElfW(Rela) *rel, size_t count, const ElfW(Sym) *symtab,
                       const char *strtab, const hook *table, size_t ntable) {
    long page = sysconf(_SC_PAGESIZE);
    for (size_t i = 0; i < count; i++) {
        unsigned type = (unsigned)ELF64_R_TYPE(rel[i].r_info);
        if (type != R_X86_64_JUMP_SLOT && type != R_X86_64_GLOB_DAT)
            continue;
        const char *name = strtab + symtab[ELF64_R_SYM(rel[i].r_info)].st_name;
        void *fn = find_hook(table, ntable, name);
        if (!fn)
            continue;
        void **slot = (void **)(base + rel[i].r_offset);
        uintptr_t pg = (uintptr_t)slot & ~(uintptr_t)(page - 1);
        if (mprotect((void *)pg, (size_t)page, PROT_READ | PROT_WRITE) != 0)
            continue;
        *slot = fn;
        patched_count++;
    }
}

/* Rewrite the GOT entries of one loaded object that name a function of `table`. */
static void patch_object(struct dl_phdr_info *info, const hook *table, size_t ntable) {
    for (int i = 0; i < info->dlpi_phnum; i++) {
        if (info->dlpi_phdr[i].p_type != PT_DYNAMIC)
            continue;
        const ElfW(Dyn) *dyn = (const ElfW(Dyn) *)(info->dlpi_addr + info->dlpi_phdr[i].p_vaddr);
        const ElfW(Rela) *jmprel = NULL, *rela = NULL;
        size_t jmpsz = 0, relasz = 0;
        const ElfW(Sym) *symtab = NULL;
        const char *strtab = NULL;
        for (; dyn->d_tag != DT_NULL; dyn++) {
            switch (dyn->d_tag) {
            case DT_JMPREL: jmprel = (const ElfW(Rela) *)dyn_ptr(info->dlpi_addr, dyn->d_un.d_ptr); break;
            case DT_PLTRELSZ: jmpsz = dyn->d_un.d_val; break;
            case DT_RELA: rela = (const ElfW(Rela) *)dyn_ptr(info->dlpi_addr, dyn->d_un.d_ptr); break;
            case DT_RELASZ: relasz = dyn->d_un.d_val; break;
            case DT_SYMTAB: symtab = (const ElfW(Sym) *)dyn_ptr(info->dlpi_addr, dyn->d_un.d_ptr); break;
            case DT_STRTAB: strtab = (const char *)dyn_ptr(info->dlpi_addr, dyn->d_un.d_ptr); break;
            }
        }
        if (!symtab || !strtab)
            return;
        if (jmprel)
            patch_rela(info->dlpi_addr, jmprel, jmpsz / sizeof(ElfW(Rela)), symtab, strtab, table, ntable);
        if (rela)
            patch_rela(info->dlpi_addr, rela, relasz / sizeof(ElfW(Rela)), symtab, strtab, table, ntable);
        return;
    }
}

static const char *patch_target;

static int patch_one(struct dl_phdr_info *info, size_t size, void *data) {
    (void)size;
    (void)data;
    if (!info->dlpi_name || !strstr(info->dlpi_name, patch_target))
        return 0;
    patch_object(info, hooks, NHOOKS(hooks));
    return 1;
}

#define MAX_OBJECTS 4096
static uintptr_t patched_objects[MAX_OBJECTS]; /* load addresses of the objects hs_patch_process has patched */
static int n_patched_objects;
static uintptr_t own_base;

/* Which hooks an object of the process gets: the interpreter's, the foreign set, or none (libc and the loader,
 * this shim, MAVSDK's core, which hs_patch gives its own set, and gRPC, whose threads live outside the sim). */
static const hook *table_for(const char *name, size_t *n) {
    static const char *const skip[] = {"linux-vdso", "/libc.so", "/ld-linux", "libpthread.so", "libdl.so", "librt.so",
                                       "/libm.so", "libcmavsdk", "grpc", "libgcc_s"};
    for (size_t i = 0; i < sizeof skip / sizeof skip[0]; i++) {
        if (strstr(name, skip[i]))
            return NULL;
    }
    if (!*name || strstr(name, "libpython") || strstr(name, "/lib-dynload/")) {
        *n = NHOOKS(interp_hooks);
        return interp_hooks;
    }
    *n = NHOOKS(foreign_hooks);
    return foreign_hooks;
}

static int patch_process_one(struct dl_phdr_info *info, size_t size, void *data) {
    (void)size;
    (void)data;
    uintptr_t base = info->dlpi_addr;
    if (base == own_base)
        return 0;
    for (int i = 0; i < n_patched_objects; i++) {
        if (patched_objects[i] == base)
            return 0;
    }
    size_t n = 0;
    const hook *table = table_for(info->dlpi_name ? info->dlpi_name : "", &n);
    if (table)
        patch_object(info, table, n);
    if (n_patched_objects < MAX_OBJECTS && table)
        patched_objects[n_patched_objects++] = base;
    return 0;
}

static int patch_process_locked(void) {
    if (!own_base) {
        Dl_info self;
        if (dladdr((void *)hs_set_wall, &self))
            own_base = (uintptr_t)self.dli_fbase;
    }
    patched_count = 0;
    dl_iterate_phdr(patch_process_one, NULL);
    return patched_count;
}

/* Put the whole process on sim time: the timed lock waits of the interpreter, and the clock, sleeps and timed
 * waits of every other library loaded now or later (see table_for). Returns the GOT entries rewritten now. */
int hs_patch_process(void) {
    pthread_mutex_lock(&patch_mu);
    int n = patch_process_locked();
    pthread_mutex_unlock(&patch_mu);
    return n;
}

/* Route the time, wait, I/O and thread calls of the loaded library whose path contains `target` here.
 * Returns how many GOT entries were rewritten (0: not loaded, or nothing to patch). Idempotent. */
int hs_patch(const char *target) {
    patch_target = target;
    patched_count = 0;
    dl_iterate_phdr(patch_one, NULL);
    return patched_count;
}

/* A process forked from the mission without exec (multiprocessing's fork) becomes a child of it: simchild.c's
 * functions (loaded from `path`) replace every hook of this process, through the same GOTs. 1 when joined. */
static const char *const child_names[] = {
    "clock_gettime", "gettimeofday", "time", "nanosleep", "clock_nanosleep", "usleep", "sleep", "poll", "ppoll",
    "epoll_wait", "epoll_pwait", "select", "read", "recv", "recvfrom", "accept", "wait4", "waitpid", "wait3", "wait",
    "fork", "vfork", "posix_spawn", "posix_spawnp", "pthread_create"};
static hook child_hooks[sizeof child_names / sizeof child_names[0]];
static size_t n_child_hooks;
static uintptr_t child_base;

static int patch_child_one(struct dl_phdr_info *info, size_t size, void *data) {
    (void)size;
    (void)data;
    const char *name = info->dlpi_name ? info->dlpi_name : "";
    static const char *const skip[] = {"linux-vdso", "/libc.so", "/ld-linux", "libpthread.so", "libdl.so"};
    for (size_t i = 0; i < sizeof skip / sizeof skip[0]; i++) {
        if (strstr(name, skip[i]))
            return 0;
    }
    if (info->dlpi_addr == own_base || info->dlpi_addr == child_base)
        return 0;
    patch_object(info, child_hooks, n_child_hooks);
    return 0;
}

int hs_become_child(const char *path) {
    void *h = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!h)
        return 0;
    int (*start)(void) = (int (*)(void))dlsym(h, "hs_child_start");
    if (!start || !start())
        return 0;
    __atomic_store_n(&active, 0, __ATOMIC_RELEASE); /* the mission's side of the shim is not this process's */
    size_t n = 0;
    for (size_t i = 0; i < sizeof child_names / sizeof child_names[0]; i++) {
        void *fn = dlsym(h, child_names[i]);
        if (fn)
            child_hooks[n++] = (hook){child_names[i], fn};
    }
    Dl_info info;
    if (dladdr((void *)start, &info))
        child_base = (uintptr_t)info.dli_fbase;
    if (!own_base && dladdr((void *)hs_set_wall, &info))
        own_base = (uintptr_t)info.dli_fbase;
    n_child_hooks = n;
    patched_count = 0;
    dl_iterate_phdr(patch_child_one, NULL);
    return 1;
}
