/* Writing text files with every error seen, the free space of a file system, and a lock
 * held for the life of the process, for Fortran. gfortran's buffered WRITE, FLUSH and CLOSE
 * report no error when the disk is full: 24 kB written to an 8 kB file system came back with
 * status 0 and left an 8 kB file, so an .xdmf or a forces file cut short kept its final
 * name. Here every write(2) and close(2) is checked. */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <unistd.h>

static void copy_message(int err, char *message, int capacity)
{
    const char *text = strerror(err);
    int k = 0;
    for (; k < capacity && text[k] != '\0'; ++k)
        message[k] = text[k];
    for (; k < capacity; ++k)
        message[k] = ' ';
}

/* Writes the n bytes of data to path, replacing its contents (append == 0) or after them.
 * A failed append truncates the file back to its size before it, so no partial row is left.
 * Returns 0, or the errno of the first failure with strerror's text in message (capacity
 * bytes, blank-padded for Fortran). */
int sph_write_bytes(const char *path, const char *data, long long n, int append,
                    char *message, int capacity)
{
    int fd, err = 0, known_size = 0;
    off_t before = 0;
    struct stat status;
    fd = open(path, O_WRONLY | O_CREAT | (append ? O_APPEND : O_TRUNC), 0666);
    if (fd < 0) {
        err = errno;
        copy_message(err, message, capacity);
        return err;
    }
    if (append && fstat(fd, &status) == 0) {
        before = status.st_size;
        known_size = 1;
    }
    while (n > 0) {
        ssize_t written = write(fd, data, (size_t)n);
        if (written < 0) {
            if (errno == EINTR)
                continue;
            err = errno;
            break;
        }
        if (written == 0) {
            err = EIO;
            break;
        }
        data += written;
        n -= written;
    }
    /* a parallel or network file system may report a full disk only when the data reach
     * it (fsync); a device without it (EINVAL, EROFS for special files) has nothing to add */
    if (err == 0 && fsync(fd) != 0 && errno != EINVAL && errno != EROFS)
        err = errno;
    if (err != 0 && known_size && ftruncate(fd, before) != 0) {
        /* the file keeps a partial row; the error reported is the write's */
    }
    /* (on Linux a close interrupted by a signal has closed the file all the same) */
    if (close(fd) != 0 && err == 0 && errno != EINTR)
        err = errno;
    if (err != 0)
        copy_message(err, message, capacity);
    return err;
}

/* Bytes available to an unprivileged writer on the file system holding path, or -1 when it
 * cannot be asked. */
long long sph_free_bytes(const char *path)
{
    struct statvfs fs;
    /* (a file system that reports no blocks at all, some FUSE and object-store mounts,
     * cannot say how much room it has) */
    if (statvfs(path, &fs) != 0 || fs.f_blocks == 0)
        return -1;
    return (long long)fs.f_bavail * (long long)fs.f_frsize;
}

/* Takes an advisory write lock (fcntl) on path, created if missing, and holds it for the
 * rest of the process: the kernel releases it when the process ends, however it ends (an
 * error, a signal, SIGKILL), so a lock is never left stale. The file then says who holds it
 * (host, process, batch job, start time). Returns 0 when held; 1 when another process holds
 * it (holder takes the file's text); 2 when the file system has no locks; 3 when the file
 * cannot be opened (holder takes the reason). holder: capacity bytes, blank-padded for
 * Fortran. The descriptor stays open: closing any descriptor of the file would release the
 * lock. */
int sph_lock_file(const char *path, char *holder, int capacity)
{
    int fd, err, k, n, attempt;
    struct stat held, named;
    ssize_t got;
    struct flock lock;
    char text[512], host[256];
    const char *job;
    time_t now;
    struct tm utc;
    for (k = 0; k < capacity; ++k)
        holder[k] = ' ';
    for (attempt = 0;; ++attempt) {
        /* (the mode as for every output file: the umask decides, so a group's folder
         * stays usable by the group) */
        /* (not through a symbolic link: the note would replace the contents of whatever
         * file it leads to) */
        fd = open(path, O_RDWR | O_CREAT | O_NOFOLLOW | O_NONBLOCK, 0666);
        if (fd < 0) {
            if (errno == ELOOP) {
                const char *text_link = "it is a symbolic link, not a file: remove it";
                for (k = 0; k < capacity && text_link[k] != '\0'; ++k)
                    holder[k] = text_link[k];
            } else {
                copy_message(errno, holder, capacity);
            }
            return 3;
        }
        memset(&lock, 0, sizeof lock);
        lock.l_type = F_WRLCK;
        lock.l_whence = SEEK_SET;
        if (fcntl(fd, F_SETLK, &lock) != 0) {
            err = errno;
            if (err == EACCES || err == EAGAIN) {
                got = pread(fd, text, sizeof text - 1, 0);
                for (k = 0; got > 0 && k < got && k < capacity; ++k)
                    holder[k] = text[k] == '\n' ? ' ' : text[k];
                close(fd);
                return 1;
            }
            close(fd);
            return 2;
        }
        /* the lock is the file's (its inode's), not the name's: a run that ends removes the
         * name, and one that opened the file just before then locks a file no longer in
         * the folder while a third run makes and locks a new one. Held only while the
         * name still leads to the locked file; else again, on the file now there. */
        if (fstat(fd, &held) == 0 && !S_ISREG(held.st_mode)) {
            const char *text_kind = "it is not a regular file: remove it";
            for (k = 0; k < capacity && text_kind[k] != '\0'; ++k)
                holder[k] = text_kind[k];
            close(fd);
            return 3;
        }
        if (fstat(fd, &held) == 0 && stat(path, &named) == 0 && held.st_ino == named.st_ino &&
            held.st_dev == named.st_dev)
            break;
        close(fd);
        /* (the name keeps moving under us: other runs take and leave it) */
        if (attempt == 100)
            return 1;
    }
    if (gethostname(host, sizeof host) != 0)
        strcpy(host, "unknown");
    host[sizeof host - 1] = '\0';
    job = getenv("SLURM_JOB_ID");
    if (job == NULL)
        job = getenv("PBS_JOBID");
    now = time(NULL);
    gmtime_r(&now, &utc);
    n = snprintf(text, sizeof text,
                 "host %s, process %ld, job %s, since %04d-%02d-%02dT%02d:%02d:%02dZ\n", host,
                 (long)getpid(), job ? job : "none", utc.tm_year + 1900, utc.tm_mon + 1,
                 utc.tm_mday, utc.tm_hour, utc.tm_min, utc.tm_sec);
    if (n > (int)sizeof text - 1)
        n = (int)sizeof text - 1;
    if (ftruncate(fd, 0) == 0 && n > 0) {
        if (pwrite(fd, text, (size_t)n, 0) < 0) {
            /* the lock holds all the same; only the note for a second run is missing */
        }
    }
    return 0;
}

/* What the directory entry path is, without following a link: 0 none, 1 a regular file,
 * 2 a symbolic link (dangling, or to anything but a character device), 3 a directory,
 * 4 anything else, 5 a link to a character device (/dev/full standing in for a full disk in
 * the tests: writing there loses nothing). */
int sph_entry_kind(const char *path)
{
    struct stat status, target;
    if (lstat(path, &status) != 0)
        return 0;
    if (S_ISLNK(status.st_mode)) {
        if (stat(path, &target) == 0 && S_ISCHR(target.st_mode))
            return 5;
        return 2;
    }
    if (S_ISREG(status.st_mode))
        return 1;
    if (S_ISDIR(status.st_mode))
        return 3;
    return 4;
}
