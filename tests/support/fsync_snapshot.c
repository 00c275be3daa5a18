/* A power cut, simulated: an LD_PRELOAD library that, at every fsync and fdatasync of the
 * database BTF_POWERCUT_DB (the file itself, its -wal or -journal), copies that file's whole
 * content into BTF_POWERCUT_DIR. After a SIGKILL the directory holds, for each file, what the
 * last sync made durable: the only bytes a power cut is sure to leave. A copy is written
 * beside its name and renamed over it, so a kill mid-copy leaves the previous one (the sync
 * had not returned yet). BTF_POWERCUT_DIR/syncs counts the syncs copied, one line each.
 * Built by tests/system/test_power_cut.py with the system's C compiler. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <fcntl.h>
#include <limits.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;

static int copy_file(const char *from, const char *to) {
    int in = open(from, O_RDONLY | O_CLOEXEC);
    if (in < 0)
        return -1;
    int out = open(to, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    if (out < 0) {
        close(in);
        return -1;
    }
    char buf[1 << 16];
    ssize_t n;
    int rc = 0;
    while ((n = read(in, buf, sizeof buf)) > 0) {
        if (write(out, buf, (size_t)n) != n) {
            rc = -1;
            break;
        }
    }
    if (n < 0)
        rc = -1;
    close(in);
    close(out);
    return rc;
}

static void snapshot(int fd) {
    const char *db = getenv("BTF_POWERCUT_DB");
    const char *dir = getenv("BTF_POWERCUT_DIR");
    char link[64], path[PATH_MAX], to[PATH_MAX], tmp[PATH_MAX + 8];
    if (db == NULL || dir == NULL)
        return;
    snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
    ssize_t n = readlink(link, path, sizeof path - 1);
    if (n < 0)
        return;
    path[n] = '\0';
    size_t k = strlen(db);
    if (strncmp(path, db, k) != 0)
        return;
    const char *suffix = path + k;
    if (strcmp(suffix, "") != 0 && strcmp(suffix, "-wal") != 0 && strcmp(suffix, "-journal") != 0)
        return;
    const char *base = strrchr(path, '/');
    snprintf(to, sizeof to, "%s/%s", dir, base ? base + 1 : path);
    snprintf(tmp, sizeof tmp, "%s.part", to);
    if (copy_file(path, tmp) == 0 && rename(tmp, to) == 0) {
        char count[PATH_MAX];
        snprintf(count, sizeof count, "%s/syncs", dir);
        int c = open(count, O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0600);
        if (c >= 0) {
            dprintf(c, "%s\n", base ? base + 1 : path);
            close(c);
        }
    }
}

static int synced(int fd, const char *name) {
    int (*real)(int) = (int (*)(int))dlsym(RTLD_NEXT, name);
    int rc = real(fd);
    if (rc == 0) {
        pthread_mutex_lock(&lock);
        snapshot(fd);
        pthread_mutex_unlock(&lock);
    }
    return rc;
}

int fsync(int fd) { return synced(fd, "fsync"); }

int fdatasync(int fd) { return synced(fd, "fdatasync"); }
