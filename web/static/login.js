import { api, showError } from "/static/common.js";

const form = document.querySelector("#login");
const error = document.querySelector("#error");
form.addEventListener("submit", async (event) => {
  event.preventDefault();
  error.hidden = true;
  try {
    await api("/api/login", { method: "POST", body: { username: form.username.value, password: form.password.value } });
    location.assign("/");
  } catch (err) {
    showError(error, err);
  }
});
