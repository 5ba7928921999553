#include "bench/child_process.h"

#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstring>
#include <stdexcept>

namespace dvx {

bool run_in_child(const std::function<std::string()>& work, std::string& result, std::string& error) {
  int fds[2];
  if (pipe(fds) != 0) throw std::runtime_error("bench: pipe() failed");
  std::fflush(nullptr);
  const pid_t pid = fork();
  if (pid < 0) throw std::runtime_error("bench: fork() failed");
  if (pid == 0) {
    // Child: run the work, write its text (or the error's), exit without running destructors.
    close(fds[0]);
    int code = 0;
    std::string text;
    try {
      text = work();
    } catch (const std::exception& e) {
      text = e.what();
      code = 3;
    }
    size_t written = 0;
    while (written < text.size()) {
      const ssize_t n = write(fds[1], text.data() + written, text.size() - written);
      if (n <= 0) break;
      written += size_t(n);
    }
    close(fds[1]);
    _exit(code);
  }
  // Parent: read everything, then reap the child.
  close(fds[1]);
  std::string bytes;
  char buffer[4096];
  for (ssize_t n; (n = read(fds[0], buffer, sizeof buffer)) > 0;) bytes.append(buffer, size_t(n));
  close(fds[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  if (WIFEXITED(status) && WEXITSTATUS(status) == 0) {
    result = std::move(bytes);
    return true;
  }
  if (WIFSIGNALED(status)) {
    error = std::string("child process killed by signal ") + std::to_string(WTERMSIG(status)) + " (" +
            strsignal(WTERMSIG(status)) + ")";
  } else {
    error = bytes.empty() ? "child process failed" : bytes;
  }
  return false;
}

}  // namespace dvx
