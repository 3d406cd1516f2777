/* flexlink's win64 call server: loads an FMU's win64 DLL under Wine and makes the calls that the linux64 call
 * proxy (call_proxy.c) receives, one at a time, over its standard input and output (the wire: call_wire.h).
 *
 *   call_server.exe DLL            serve calls until the proxy closes the pipe
 *   call_server.exe --exports DLL  load the DLL and print the names it exports, one a line (the proxy exports
 *                                  the same, so that a missing symbol is missing on both sides)
 *
 * The server knows no FMI signature.  A request gives each argument as 64 bits (a scalar, or the address of
 * memory the server lends); the call is made through a variadic pointer, for which the Windows x64 convention
 * passes each floating-point argument both in its XMM register and in the integer register of its position,
 * and every argument past the fourth in an 8-byte stack slot: so a function that expects a double finds its
 * bits where it looks, and one that expects an integer or a pointer finds them in its register.  No FMI
 * function takes a double first or returns one.
 *
 * What the DLL does that ends the process ends the server the same way: an exception nobody handles (an
 * access violation, ...) is reported to the proxy ('X' and its code) before the server exits; exit(n) ends it
 * with status n.  A reader thread takes the requests, so that the pipe's end (the proxy's process was killed,
 * after a call that did not return) ends the server even while the DLL's call still runs.
 */
#include <windows.h>
#include <fcntl.h>
#include <io.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "call_wire.h"

#define MAX_ARGS 16

static HANDLE wire_in, wire_out;
static CRITICAL_SECTION writing;

/* ------------------------------------------------------------------------------------------- frames out */

typedef struct { unsigned char *data; size_t size, capacity; } Buffer;

static void put(Buffer *b, const void *p, size_t n) {
    if (b->size + n > b->capacity) {
        b->capacity = (b->size + n) * 2 + 64;
        b->data = realloc(b->data, b->capacity);
        if (b->data == NULL) ExitProcess(70);
    }
    if (n) memcpy(b->data + b->size, p, n);
    b->size += n;
}

static void put_u64(Buffer *b, uint64_t x) { put(b, &x, 8); }

static void put_string(Buffer *b, const char *s) {
    int64_t n = s == NULL ? -1 : (int64_t)strlen(s);
    put(b, &n, 8);
    if (s != NULL) put(b, s, (size_t)n);
}

static void write_all(HANDLE h, const void *p, size_t n) {
    const char *c = p;
    while (n > 0) {
        DWORD done = 0;
        if (!WriteFile(h, c, n > 1u << 30 ? 1u << 30 : (DWORD)n, &done, NULL) || done == 0) ExitProcess(71);
        c += done;
        n -= done;
    }
}

/* a frame: its length, then its bytes, in one write (b->data begins with 8 bytes kept for the length) */
static void send_frame(Buffer *b) {
    uint64_t n = b->size - 8;
    memcpy(b->data, &n, 8);
    EnterCriticalSection(&writing);
    write_all(wire_out, b->data, b->size);
    LeaveCriticalSection(&writing);
    b->size = 8;
}

static void begin_frame(Buffer *b, const char *tag) {
    uint64_t zero = 0;
    b->size = 0;
    put(b, &zero, 8);
    put(b, tag, 1);
}

/* ------------------------------------------------------------------------------------------- the callbacks */

static void log_frame(uint64_t env, int status, const char *name, const char *category, const char *text,
                      int fmi3) {
    Buffer b = {0};
    begin_frame(&b, "L");
    put_u64(&b, env);
    put(&b, &status, 4);
    put_string(&b, name);
    put_string(&b, category);
    put_string(&b, text);
    put(&b, &fmi3, 4);
    send_frame(&b);
    free(b.data);
}

/* FMI 2's logger: the message is a format, formatted here (the proxy hands it on with '%' escaped) */
static void logger2(void *env, const char *name, int status, const char *category, const char *format, ...) {
    char text[8192];
    va_list ap;
    va_start(ap, format);
    vsnprintf(text, sizeof text, format != NULL ? format : "", ap);
    va_end(ap);
    log_frame((uint64_t)(uintptr_t)env, status, name, category, format != NULL ? text : NULL, 0);
}

static void logger3(void *env, int status, const char *category, const char *message) {
    log_frame((uint64_t)(uintptr_t)env, status, NULL, category, message, 1);
}

static void *allocate(size_t n, size_t size) { return calloc(n, size); }

typedef struct {
    void (*logger)(void *, const char *, int, const char *, const char *, ...);
    void *(*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void *);
    void (*stepFinished)(void *, int);
    void *componentEnvironment;
} Callbacks2;   /* fmi2CallbackFunctions */

/* ------------------------------------------------------------------------------------------- exceptions */

static LONG WINAPI unhandled(EXCEPTION_POINTERS *e) {
    Buffer b = {0};
    uint32_t code = e->ExceptionRecord->ExceptionCode;
    begin_frame(&b, "X");
    put(&b, &code, 4);
    send_frame(&b);
    TerminateProcess(GetCurrentProcess(), code);
    return EXCEPTION_EXECUTE_HANDLER;
}

/* ------------------------------------------------------------------------------------------- one call */

typedef struct { const unsigned char *p, *end; } Reader;

static void take(Reader *r, void *dst, size_t n) {
    if ((size_t)(r->end - r->p) < n) ExitProcess(72);          /* a malformed request: the proxy's bug */
    memcpy(dst, r->p, n);
    r->p += n;
}

static uint64_t take_u64(Reader *r) { uint64_t x; take(r, &x, 8); return x; }

static char *take_string(Reader *r) {
    int64_t n;
    char *s;
    take(r, &n, 8);
    if (n < 0) return NULL;
    s = malloc((size_t)n + 1);
    take(r, s, (size_t)n);
    s[n] = '\0';
    return s;
}

typedef struct { int kind; uint64_t size, count, sizes_arg; void *memory; } Arg;

typedef uint64_t (*AnyFunction)(uint64_t, ...);

static uint64_t invoke(FARPROC f, const uint64_t *a) {
    double d[MAX_ARGS];
    int k;
    for (k = 0; k < MAX_ARGS; k++) memcpy(&d[k], &a[k], 8);
    return ((AnyFunction)(void (*)(void))f)(a[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7], d[8], d[9], d[10],
                                            d[11], d[12], d[13], d[14], d[15]);
}

/* decode argument k of the request into its 64-bit value, lending memory where it points */
static uint64_t decode(Reader *r, Arg *arg) {
    unsigned char kind;
    uint64_t i;
    take(r, &kind, 1);
    arg->kind = kind;
    switch (kind) {
    case ARG_SCALAR: return take_u64(r);
    case ARG_NULL: return 0;
    case ARG_IN: case ARG_OUT: case ARG_INOUT:
        arg->size = take_u64(r);
        arg->memory = calloc(arg->size ? arg->size : 1, 1);
        if (kind != ARG_OUT) take(r, arg->memory, arg->size);
        return (uint64_t)(uintptr_t)arg->memory;
    case ARG_STRING:
        arg->memory = take_string(r);
        return (uint64_t)(uintptr_t)arg->memory;
    case ARG_STRINGS_IN: case ARG_STRINGS_OUT: case ARG_BINARIES_IN: case ARG_BINARIES_OUT:
        arg->count = take_u64(r);
        arg->memory = calloc(arg->count ? arg->count : 1, sizeof(void *));
        if (kind == ARG_BINARIES_OUT) arg->sizes_arg = take_u64(r);
        for (i = 0; i < arg->count && kind == ARG_STRINGS_IN; i++) ((char **)arg->memory)[i] = take_string(r);
        for (i = 0; i < arg->count && kind == ARG_BINARIES_IN; i++) {
            uint64_t n = take_u64(r);
            unsigned char *bytes = malloc(n ? n : 1);
            take(r, bytes, n);
            ((unsigned char **)arg->memory)[i] = bytes;
        }
        return (uint64_t)(uintptr_t)arg->memory;
    case ARG_CALLBACKS2: {
        uint64_t mask = take_u64(r);
        Callbacks2 *c = calloc(1, sizeof *c);          /* kept: the DLL may hold it for the instance's life */
        c->logger = (mask & 1) ? logger2 : NULL;
        c->allocateMemory = (mask & 2) ? allocate : NULL;
        c->freeMemory = (mask & 4) ? free : NULL;
        c->componentEnvironment = (void *)(uintptr_t)take_u64(r);
        return (uint64_t)(uintptr_t)c;
    }
    case ARG_LOGGER3: return (uint64_t)(uintptr_t)logger3;
    default: ExitProcess(73);
    }
    return 0;
}

/* the result frame: the return value, then what the DLL wrote into lent memory */
static void reply(Buffer *b, uint32_t ret, uint64_t value, Arg *args, uint32_t n) {
    uint32_t k;
    uint64_t i;
    begin_frame(b, "R");
    put_u64(b, value);
    if (ret == RET_STRING) put_string(b, (const char *)(uintptr_t)value);
    for (k = 0; k < n; k++) {
        Arg *a = &args[k];
        if (a->kind == ARG_OUT || a->kind == ARG_INOUT) put(b, a->memory, a->size);
        for (i = 0; i < a->count && a->kind == ARG_STRINGS_OUT; i++) put_string(b, ((char **)a->memory)[i]);
        for (i = 0; i < a->count && a->kind == ARG_BINARIES_OUT; i++) {
            const size_t *sizes = (const size_t *)args[a->sizes_arg].memory;
            const unsigned char *bytes = ((unsigned char **)a->memory)[i];
            uint64_t size = bytes != NULL && sizes != NULL ? sizes[i] : 0;
            put_u64(b, size);
            put(b, bytes, size);
        }
    }
}

/* the memory lent for one call, freed after it: FMI makes the receiver copy what it keeps (an instantiation's
 * strings are kept all the same, and the callbacks, which FMI 2 lets the FMU hold until it is freed) */
static void release(Arg *args, uint32_t n) {
    uint32_t k;
    uint64_t i;
    for (k = 0; k < n; k++) {
        Arg *a = &args[k];
        for (i = 0; i < a->count && (a->kind == ARG_STRINGS_IN || a->kind == ARG_BINARIES_IN); i++)
            free(((void **)a->memory)[i]);
        if (a->kind != ARG_CALLBACKS2) free(a->memory);
    }
}

static void serve(HMODULE dll, const unsigned char *request, size_t size) {
    Reader r = {request, request + size};
    uint32_t ret, length, n, k;
    uint64_t a[MAX_ARGS] = {0}, value;
    Arg args[MAX_ARGS];
    char name[256];
    FARPROC f;
    Buffer b = {0};
    memset(args, 0, sizeof args);
    take(&r, &ret, 4);
    take(&r, &length, 4);
    if (length >= sizeof name) ExitProcess(74);
    take(&r, name, length);
    name[length] = '\0';
    take(&r, &n, 4);
    if (n > MAX_ARGS) ExitProcess(75);
    for (k = 0; k < n; k++) a[k] = decode(&r, &args[k]);
    f = GetProcAddress(dll, name);
    if (f == NULL) {
        begin_frame(&b, "E");
        put_string(&b, "the DLL does not export this function");
    } else {
        value = invoke(f, a);
        if (ret == RET_INT) value = (uint64_t)(uint32_t)value;
        reply(&b, ret, value, args, n);
    }
    send_frame(&b);
    free(b.data);
    if (strstr(name, "Instantiate") == NULL) release(args, n);
}

/* ------------------------------------------------------------------------------------------- requests in */

/* the hand-over between the reader and the main thread: a lock and a condition variable, which Wine builds
 * on futexes (events would cost a round trip to the wineserver each, most of a call's time) */
static SRWLOCK lock = SRWLOCK_INIT;
static CONDITION_VARIABLE changed = CONDITION_VARIABLE_INIT;
static unsigned char *request;                  /* a request the main thread has not taken yet, or NULL */
static size_t request_size;
static int busy;                                /* the main thread is serving a request */

static int read_all(void *p, size_t n) {
    char *c = p;
    while (n > 0) {
        DWORD done = 0;
        if (!ReadFile(wire_in, c, n > 1u << 30 ? 1u << 30 : (DWORD)n, &done, NULL) || done == 0) return 0;
        c += done;
        n -= done;
    }
    return 1;
}

/* the reader: it goes on reading while the DLL's call runs, so that the end of the pipe (the proxy's process
 * is gone, killed after a call that did not return) ends the server at once */
static DWORD WINAPI reader(void *unused) {
    uint64_t n;
    unsigned char *frame;
    (void)unused;
    for (;;) {
        if (!read_all(&n, 8)) break;
        frame = malloc(n ? n : 1);
        if (frame == NULL || !read_all(frame, n)) break;
        AcquireSRWLockExclusive(&lock);
        while (request != NULL || busy) SleepConditionVariableSRW(&changed, &lock, INFINITE, 0);
        request = frame;
        request_size = n;
        WakeAllConditionVariable(&changed);
        ReleaseSRWLockExclusive(&lock);
    }
    TerminateProcess(GetCurrentProcess(), 0);
    return 0;
}

static int list_exports(HMODULE dll) {
    const unsigned char *base = (const unsigned char *)dll;
    const IMAGE_NT_HEADERS *nt = (const IMAGE_NT_HEADERS *)(base + ((const IMAGE_DOS_HEADER *)base)->e_lfanew);
    const IMAGE_DATA_DIRECTORY *dir = &nt->OptionalHeader.DataDirectory[IMAGE_DIRECTORY_ENTRY_EXPORT];
    const IMAGE_EXPORT_DIRECTORY *exports;
    const DWORD *names;
    DWORD k;
    if (dir->Size == 0) return 0;
    exports = (const IMAGE_EXPORT_DIRECTORY *)(base + dir->VirtualAddress);
    names = (const DWORD *)(base + exports->AddressOfNames);
    for (k = 0; k < exports->NumberOfNames; k++) printf("%s\n", (const char *)(base + names[k]));
    return 0;
}

int main(int argc, char **argv) {
    const char *path = argc == 3 && strcmp(argv[1], "--exports") == 0 ? argv[2] : argc == 2 ? argv[1] : NULL;
    HMODULE dll;
    HANDLE thread;
    if (path == NULL) {
        fprintf(stderr, "usage: call_server.exe [--exports] DLL\n");
        return 2;
    }
    SetErrorMode(SEM_FAILCRITICALERRORS | SEM_NOGPFAULTERRORBOX);
    dll = LoadLibraryA(path);
    if (dll == NULL) {
        fprintf(stderr, "call_server: cannot load %s (Windows error %lu)\n", path, (unsigned long)GetLastError());
        return 3;
    }
    if (argc == 3) return list_exports(dll);
    /* the wire keeps the standard output's handle; what the DLL prints goes to the standard error */
    wire_in = GetStdHandle(STD_INPUT_HANDLE);
    DuplicateHandle(GetCurrentProcess(), GetStdHandle(STD_OUTPUT_HANDLE), GetCurrentProcess(), &wire_out, 0,
                    FALSE, DUPLICATE_SAME_ACCESS);
    _dup2(2, 1);
    SetStdHandle(STD_OUTPUT_HANDLE, GetStdHandle(STD_ERROR_HANDLE));
    InitializeCriticalSection(&writing);
    SetUnhandledExceptionFilter(unhandled);
    thread = CreateThread(NULL, 0, reader, NULL, 0, NULL);
    if (thread == NULL) return 4;
    for (;;) {
        unsigned char *frame;
        size_t size;
        AcquireSRWLockExclusive(&lock);
        while (request == NULL) SleepConditionVariableSRW(&changed, &lock, INFINITE, 0);
        frame = request;
        size = request_size;
        request = NULL;
        busy = 1;
        ReleaseSRWLockExclusive(&lock);
        serve(dll, frame, size);
        free(frame);
        AcquireSRWLockExclusive(&lock);
        busy = 0;
        WakeAllConditionVariable(&changed);
        ReleaseSRWLockExclusive(&lock);
    }
}
