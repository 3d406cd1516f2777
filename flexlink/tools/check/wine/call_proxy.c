/* flexlink's linux64 call proxy: the wire to the win64 call server (call_server.c) under Wine.
 *
 * The proxy sits at binaries/linux64/<id>.so (FMI 3: binaries/x86_64-linux/) of an FMU whose win64 DLL is at
 * binaries/win64/<id>.dll (x86_64-windows/), with call_server.exe beside the DLL.  The first call starts the
 * server (`$FLEXLINK_WINE` or `wine`, `call_server.exe Z:\...\<id>.dll`) with a pipe to each side; it lives
 * until the library is unloaded.  One call at a time: a request, then log messages and the result.
 *
 * What ends the server ends this process the same way, so that a host sees what a native binary would have
 * done to it: an exception in the DLL (reported by the server) is the matching signal (an access violation
 * SIGSEGV, ...); an exit(n) in the DLL is _exit(n).  One line on the standard error says which call it was.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <fcntl.h>
#include <pthread.h>
#include <time.h>
#include <errno.h>
#include <signal.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "call_proxy.h"

extern char **environ;

static pid_t server = -1;
static int to_server = -1, from_server = -1;

/* ------------------------------------------------------------------------------------------- the end */

/* the proxy cannot reach the server: one line, and the process ends as an abort */
static void give_up(const char *call, const char *why) {
    fprintf(stderr, "flexlink call proxy: %s (in %s)\n", why, call);
    fflush(NULL);
    signal(SIGABRT, SIG_DFL);
    raise(SIGABRT);
    _exit(134);
}

static void die_like(const char *call, int status_or_code, int exception) {
    int sig = SIGABRT;
    if (exception) {
        unsigned code = (unsigned)status_or_code;
        sig = code == 0xC0000005u || code == 0xC00000FDu ? SIGSEGV
            : (code >= 0xC000008Du && code <= 0xC0000095u) ? SIGFPE
            : code == 0xC000001Du ? SIGILL : SIGABRT;
        fprintf(stderr, "flexlink call proxy: the win64 DLL raised exception 0x%08X in %s\n", code, call);
    } else if (WIFEXITED(status_or_code)) {
        fprintf(stderr, "flexlink call proxy: the win64 DLL ended the process (exit status %d) in %s\n",
                WEXITSTATUS(status_or_code), call);
        fflush(NULL);
        _exit(WEXITSTATUS(status_or_code));
    } else {
        fprintf(stderr, "flexlink call proxy: the win64 call server ended unexpectedly in %s\n", call);
    }
    fflush(NULL);
    signal(sig, SIG_DFL);
    raise(sig);
    _exit(128 + sig);
}

static int server_status(void) {
    int status = 0;
    if (server > 0 && waitpid(server, &status, 0) == server) server = -1;
    return status;
}

/* ------------------------------------------------------------------------------------------- the pipes */

static int write_all(const void *p, size_t n) {
    const char *c = p;
    sigset_t pipe_signal, old;
    int ok = 1;
    struct timespec now = {0, 0};
    sigemptyset(&pipe_signal);
    sigaddset(&pipe_signal, SIGPIPE);
    pthread_sigmask(SIG_BLOCK, &pipe_signal, &old);     /* a server that is gone: an error, not SIGPIPE */
    while (n > 0 && ok) {
        ssize_t done = write(to_server, c, n);
        if (done < 0 && errno == EINTR) continue;
        ok = done > 0;
        if (ok) { c += done; n -= (size_t)done; }
    }
    while (sigtimedwait(&pipe_signal, NULL, &now) > 0) {}
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    return ok;
}

static int read_all(void *p, size_t n) {
    char *c = p;
    while (n > 0) {
        ssize_t done = read(from_server, c, n);
        if (done < 0 && errno == EINTR) continue;
        if (done <= 0) return 0;
        c += done;
        n -= (size_t)done;
    }
    return 1;
}

/* where this library is: the DLL and the server are in the sibling folder of the other platform */
static int locate(char *dll, char *exe, size_t size) {
    Dl_info info;
    const char *slash, *folder, *other;
    char base[4096];
    size_t dir;
    if (!dladdr((void *)locate, &info) || info.dli_fname == NULL) return 0;
    slash = strrchr(info.dli_fname, '/');
    if (slash == NULL) return 0;
    dir = (size_t)(slash - info.dli_fname);
    if (dir >= sizeof base) return 0;
    memcpy(base, info.dli_fname, dir);
    base[dir] = '\0';
    folder = strrchr(base, '/');
    if (folder == NULL) return 0;
    other = strcmp(folder + 1, "x86_64-linux") == 0 ? "x86_64-windows" : "win64";
    base[folder - base] = '\0';
    {
        char stem[1024];
        const char *dot = strrchr(slash + 1, '.');
        size_t k = dot != NULL ? (size_t)(dot - slash - 1) : strlen(slash + 1);
        if (k >= sizeof stem) return 0;
        memcpy(stem, slash + 1, k);
        stem[k] = '\0';
        snprintf(dll, size, "%s/%s/%s.dll", base, other, stem);
        snprintf(exe, size, "%s/%s/call_server.exe", base, other);
    }
    return 1;
}

static void start_server(const char *call) {
    char dll[4096], exe[4096], *windows_dll;
    int in[2], out[2];
    const char *wine = getenv("FLEXLINK_WINE");
    char *argv[4];
    posix_spawn_file_actions_t actions;
    if (!locate(dll, exe, sizeof dll)) give_up(call, "cannot find the win64 DLL beside this library");
    windows_dll = windows_path(dll);
    if (windows_dll == NULL || pipe2(in, O_CLOEXEC) != 0 || pipe2(out, O_CLOEXEC) != 0)
        give_up(call, "cannot make the pipes to the call server");
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, in[0], 0);
    posix_spawn_file_actions_adddup2(&actions, out[1], 1);
    argv[0] = (char *)(wine != NULL && *wine ? wine : "wine");
    argv[1] = exe;
    argv[2] = windows_dll;
    argv[3] = NULL;
    if (posix_spawnp(&server, argv[0], &actions, NULL, argv, environ) != 0) {
        server = -1;
        give_up(call, "cannot run Wine ($FLEXLINK_WINE or wine)");
    }
    posix_spawn_file_actions_destroy(&actions);
    free(windows_dll);
    close(in[0]);
    close(out[1]);
    to_server = in[1];
    from_server = out[0];
}

__attribute__((destructor)) static void stop_server(void) {
    if (to_server >= 0) close(to_server);
    if (from_server >= 0) close(from_server);
    to_server = from_server = -1;
    server_status();
}

/* ------------------------------------------------------------------------------------------- a request */

static void put(Call *c, const void *p, size_t n) {
    if (c->size + n > c->capacity) {
        c->capacity = (c->size + n) * 2 + 256;
        c->data = realloc(c->data, c->capacity);
        if (c->data == NULL) give_up(c->name, "out of memory");
    }
    if (n) memcpy(c->data + c->size, p, n);
    c->size += n;
}

static void put_u64(Call *c, uint64_t x) { put(c, &x, 8); }

static void put_string(Call *c, const char *s) {
    int64_t n = s == NULL ? -1 : (int64_t)strlen(s);
    put(c, &n, 8);
    if (s != NULL) put(c, s, (size_t)n);
}

/* the next argument: its kind, remembered for the result */
static void arg(Call *c, int kind, void *target, size_t size) {
    unsigned char k = (unsigned char)kind;
    if (c->nargs >= CALL_MAX_ARGS) give_up(c->name, "too many arguments");
    c->args[c->nargs].kind = kind;
    c->args[c->nargs].target = target;
    c->args[c->nargs].size = size;
    c->args[c->nargs].count = 0;
    c->nargs++;
    put(c, &k, 1);
}

void call_begin(Call *c, const char *name, int ret) {
    uint32_t r = (uint32_t)ret, n = (uint32_t)strlen(name), zero = 0;
    memset(c, 0, sizeof *c);
    c->name = name;
    c->ret = ret;
    put(c, &r, 4);
    put(c, &n, 4);
    put(c, name, n);
    put(c, &zero, 4);             /* the argument count, written by call_finish */
}

uint64_t pointer_bits(const void *p) { return (uint64_t)(uintptr_t)p; }

void call_scalar(Call *c, uint64_t bits) { arg(c, ARG_SCALAR, NULL, 0); put_u64(c, bits); }

void call_double(Call *c, double x) { uint64_t bits; memcpy(&bits, &x, 8); call_scalar(c, bits); }

static void lend(Call *c, int kind, void *p, size_t n) {
    if (p == NULL) { arg(c, ARG_NULL, NULL, 0); return; }
    arg(c, kind, p, n);
    put_u64(c, n);
    if (kind != ARG_OUT) put(c, p, n);
}

void call_in(Call *c, const void *p, size_t n) { lend(c, ARG_IN, (void *)p, n); }
void call_out(Call *c, void *p, size_t n) { lend(c, ARG_OUT, p, n); }
void call_inout(Call *c, void *p, size_t n) { lend(c, ARG_INOUT, p, n); }

void call_string(Call *c, const char *s) { arg(c, ARG_STRING, NULL, 0); put_string(c, s); }

void call_strings_in(Call *c, const char *const *s, size_t count) {
    size_t k;
    if (s == NULL) { arg(c, ARG_NULL, NULL, 0); return; }
    arg(c, ARG_STRINGS_IN, NULL, 0);
    put_u64(c, count);
    for (k = 0; k < count; k++) put_string(c, s[k]);
}

void call_strings_out(Call *c, const char **s, size_t count) {
    if (s == NULL) { arg(c, ARG_NULL, NULL, 0); return; }
    arg(c, ARG_STRINGS_OUT, (void *)s, 0);
    c->args[c->nargs - 1].count = count;
    put_u64(c, count);
}

void call_binaries_in(Call *c, const size_t *sizes, const unsigned char *const *values, size_t count) {
    size_t k;
    if (values == NULL || sizes == NULL) { arg(c, ARG_NULL, NULL, 0); return; }
    arg(c, ARG_BINARIES_IN, NULL, 0);
    put_u64(c, count);
    for (k = 0; k < count; k++) {
        put_u64(c, values[k] != NULL ? sizes[k] : 0);
        put(c, values[k], values[k] != NULL ? sizes[k] : 0);
    }
}

void call_binaries_out(Call *c, const unsigned char **values, size_t count, uint32_t sizes_arg) {
    if (values == NULL) { arg(c, ARG_NULL, NULL, 0); return; }
    arg(c, ARG_BINARIES_OUT, (void *)values, 0);
    c->args[c->nargs - 1].count = count;
    put_u64(c, count);
    put_u64(c, sizes_arg);
}

void call_callbacks2(Call *c, uint64_t mask, uint64_t route) {
    arg(c, ARG_CALLBACKS2, NULL, 0);
    put_u64(c, mask);
    put_u64(c, route);
}

void call_logger3(Call *c, int present) { arg(c, present ? ARG_LOGGER3 : ARG_NULL, NULL, 0); }

/* ------------------------------------------------------------------------------------------- log routes */

static LogRoute *routes;
static size_t n_routes;

uint64_t route_add(LogRoute route) {
    LogRoute *grown = realloc(routes, (n_routes + 1) * sizeof *routes);
    if (grown == NULL) return 0;
    routes = grown;
    routes[n_routes++] = route;
    return n_routes;              /* 0 stays "no route" */
}

/* FMI 2's message is a format: the server formatted it, so a '%' in the text is escaped for the host */
static char *escaped(const char *text) {
    size_t n = 0, k;
    char *out, *o;
    for (k = 0; text[k]; k++) n += text[k] == '%' ? 2 : 1;
    out = o = malloc(n + 1);
    if (out == NULL) return NULL;
    for (k = 0; text[k]; k++) {
        *o++ = text[k];
        if (text[k] == '%') *o++ = '%';
    }
    *o = '\0';
    return out;
}

/* ------------------------------------------------------------------------------------------- replies */

typedef struct { const unsigned char *p, *end; } Reader;

static int take(Reader *r, void *dst, size_t n) {
    if ((size_t)(r->end - r->p) < n) return 0;
    if (n) memcpy(dst, r->p, n);
    r->p += n;
    return 1;
}

static char *take_string(Reader *r) {
    int64_t n;
    char *s;
    if (!take(r, &n, 8) || n < 0) return NULL;
    s = malloc((size_t)n + 1);
    if (s == NULL || !take(r, s, (size_t)n)) { free(s); return NULL; }
    s[n] = '\0';
    return s;
}

/* strings the DLL gave out (fmi2GetString, ...): valid until the next call that gives strings */
static char **pool;
static size_t n_pool;

static char *keep(char *s) {
    char **grown;
    if (s == NULL) return NULL;
    grown = realloc(pool, (n_pool + 1) * sizeof *pool);
    if (grown == NULL) return s;
    pool = grown;
    pool[n_pool++] = s;
    return s;
}

static void log_message(Reader *r) {
    uint64_t env = 0;
    int32_t status = 0, fmi3 = 0;
    char *name, *category, *text;
    take(r, &env, 8);
    take(r, &status, 4);
    name = take_string(r);
    category = take_string(r);
    text = take_string(r);
    take(r, &fmi3, 4);
    if (env >= 1 && env <= n_routes) {
        LogRoute *route = &routes[env - 1];
        if (fmi3 && route->logger3 != NULL) {
            route->logger3(route->environment, status, category, text);
        } else if (!fmi3 && route->logger2 != NULL) {
            char *message = text != NULL ? escaped(text) : NULL;
            route->logger2(route->environment, name, status, category, message);
            free(message);
        }
    }
    free(name);
    free(category);
    free(text);
}

/* the result: the return value, then what the DLL wrote, copied where the caller's pointers point */
static uint64_t result(Call *c, Reader *r) {
    uint64_t value = 0, n;
    uint32_t k;
    size_t i;
    take(r, &value, 8);
    if (c->ret == RET_STRING) value = pointer_bits(take_string(r));     /* a static string: kept for good */
    for (k = 0; k < c->nargs; k++) {
        int kind = c->args[k].kind;
        if (kind == ARG_OUT || kind == ARG_INOUT) take(r, c->args[k].target, c->args[k].size);
        for (i = 0; i < c->args[k].count && kind == ARG_STRINGS_OUT; i++)
            ((const char **)c->args[k].target)[i] = keep(take_string(r));
        for (i = 0; i < c->args[k].count && kind == ARG_BINARIES_OUT; i++) {
            unsigned char *bytes;
            if (!take(r, &n, 8)) break;
            bytes = malloc(n ? n : 1);
            if (bytes != NULL) take(r, bytes, n);
            ((const unsigned char **)c->args[k].target)[i] = (unsigned char *)keep((char *)bytes);
        }
    }
    return value;
}

static void release_pool(void) {
    size_t k;
    for (k = 0; k < n_pool; k++) free(pool[k]);
    n_pool = 0;
}

uint64_t call_finish(Call *c) {
    uint64_t size = c->size, value = 0;
    unsigned char *frame = NULL;
    uint32_t nargs = c->nargs;
    memcpy(c->data + 8 + strlen(c->name), &nargs, 4);
    for (uint32_t k = 0; k < c->nargs; k++)
        if (c->args[k].kind == ARG_STRINGS_OUT || c->args[k].kind == ARG_BINARIES_OUT) { release_pool(); break; }
    if (server < 0) start_server(c->name);
    if (!write_all(&size, 8) || !write_all(c->data, c->size)) die_like(c->name, server_status(), 0);
    for (;;) {
        Reader r;
        unsigned char tag = 0;
        uint64_t n;
        if (!read_all(&n, 8) || (frame = realloc(frame, n ? n : 1)) == NULL || !read_all(frame, n))
            die_like(c->name, server_status(), 0);
        r.p = frame;
        r.end = frame + n;
        take(&r, &tag, 1);
        if (tag == 'L') { log_message(&r); continue; }
        if (tag == 'R') { value = result(c, &r); break; }
        if (tag == 'X') { uint32_t code = 0; take(&r, &code, 4); server_status(); die_like(c->name, (int)code, 1); }
        /* 'E': the DLL does not export it (the proxy exports what the DLL does, so only by a host's misuse) */
        value = c->ret == RET_INT ? 3 : 0;                          /* fmi2Error / fmi3Error, or NULL */
        break;
    }
    free(frame);
    free(c->data);
    return value;
}

/* ------------------------------------------------------------------------------------------- paths */

char *windows_path(const char *path) {
    size_t n = strlen(path), k;
    char *out = malloc(n + 3);
    if (out == NULL) return NULL;
    out[0] = 'Z';
    out[1] = ':';
    for (k = 0; k <= n; k++) out[k + 2] = path[k] == '/' ? '\\' : path[k];
    return out;
}

char *windows_uri(const char *uri) {
    const char *prefix = "file://";
    size_t n;
    char *out;
    if (uri == NULL || strncmp(uri, prefix, 7) != 0 || uri[7] != '/') return uri != NULL ? strdup(uri) : NULL;
    n = strlen(uri);
    out = malloc(n + 4);
    if (out == NULL) return NULL;
    sprintf(out, "file:///Z:%s", uri + 7);
    return out;
}
