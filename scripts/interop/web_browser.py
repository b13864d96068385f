#!/usr/bin/env python3
"""The web dashboard in a real browser: headless Chromium driven by Selenium (Apache-2.0),
run as a separate process by crates/hartkit/tests/web_browser.rs against
`hartkit serve --sim --web ...`.

It loads the plant view and waits until every device shows a numeric PV, then until each
PV has changed (live, without reloading); opens a device page and waits for its trend;
checks that a write without logging in is refused; logs in with the administrator's
password, changes the damping through the page's form and sees it read back; opens the
traffic view and waits for frames. It saves a screenshot of each page in --shots and
prints one JSON object with what it saw.
"""

import argparse
import json
import os
import shutil
import sys
import time
import urllib.request

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By


def browser():
    opts = webdriver.ChromeOptions()
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              "--window-size=1400,1000", "--hide-scrollbars"):
        opts.add_argument(a)
    binary = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if binary:
        opts.binary_location = binary
    driver = shutil.which("chromedriver") or "/usr/lib/chromium/chromedriver"
    return webdriver.Chrome(service=Service(executable_path=driver), options=opts)


def wait(what, f, timeout):
    end = time.monotonic() + timeout
    last = None
    while time.monotonic() < end:
        try:
            last = f()
            if last:
                return last
        except Exception as e:  # the page may be re-rendering
            last = e
        time.sleep(0.2)
    raise SystemExit(f"timed out after {timeout} s waiting for {what} (last: {last!r})")


def pvs(d):
    out = {}
    for row in d.find_elements(By.CSS_SELECTOR, "#plant tbody tr"):
        cell = row.find_element(By.CSS_SELECTOR, "td.pv").text.strip()
        try:
            out[row.get_attribute("data-unit")] = float(cell)
        except ValueError:
            out[row.get_attribute("data-unit")] = None
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--password", required=True)
    ap.add_argument("--shots", required=True)
    a = ap.parse_args()
    base = a.url.rstrip("/")
    os.makedirs(a.shots, exist_ok=True)
    devices = json.load(urllib.request.urlopen(base + "/api/devices"))["devices"]
    # The devices the plant has (configured positions not answering stay "no reply").
    wanted = {str(d["unit"]) for d in devices if d["polling_address"] is not None}
    result = {"devices": len(wanted)}
    d = browser()
    try:
        d.get(base + "/")
        first = wait("a numeric PV for every device",
                     lambda: (lambda p: p if all(p.get(u) is not None for u in wanted) else None)(pvs(d)), 60)
        result["first_pvs"] = first
        api_first = {str(x["unit"]): (x["pv"] or {}).get("value")
                     for x in json.load(urllib.request.urlopen(base + "/api/devices"))["devices"]}
        # The link to device 1, found before the values change: the page updates cells in
        # place, so this very element is still on the page to click afterwards.
        link = d.find_element(By.CSS_SELECTOR, '#dev-1 a.tag')
        t0 = time.monotonic()
        # The PVs change on the page without reloading it (it is never reloaded here):
        # within 10 s, every PV the gateway has seen change has changed on the page too
        # (a valve positioner's PV, its set point, may stay put).
        seen = set()

        def live_values():
            p = pvs(d)
            seen.update(u for u in wanted if p.get(u) is not None and p.get(u) != first[u])
            api = {str(x["unit"]): (x["pv"] or {}).get("value")
                   for x in json.load(urllib.request.urlopen(base + "/api/devices"))["devices"]}
            moved = {u for u in wanted if api.get(u) != api_first.get(u)}
            return seen and moved <= seen and time.monotonic() - t0 > 5

        wait("the PVs to change on the page", live_values, 10)
        result["changed_after_s"] = round(time.monotonic() - t0, 1)
        result["changed"] = sorted(seen)
        result["live"] = d.find_element(By.ID, "live").text
        d.save_screenshot(os.path.join(a.shots, "plant.png"))

        link.click()
        wait("the device page", lambda: d.find_element(By.TAG_NAME, "body").get_attribute("data-page") == "device", 20)
        wait("the trend", lambda: d.execute_script(
            "var i = document.getElementById('trend'); return i && i.complete && i.naturalWidth > 0;"), 20)
        result["trend_has_line"] = "<path" in urllib.request.urlopen(base + "/device/1/trend.svg?window=5m").read().decode()
        result["sections"] = [s.get_attribute("id") for s in d.find_elements(By.CSS_SELECTOR, "section.read")]
        d.save_screenshot(os.path.join(a.shots, "device.png"))

        # A write without logging in: the page offers none, and the API refuses it.
        result["no_login_forms"] = len(d.find_elements(By.CSS_SELECTOR, "form.write"))
        result["refused_status"] = d.execute_async_script("""
            var done = arguments[arguments.length - 1];
            fetch('/api/devices/1/write', {method: 'POST', headers: {'Content-Type': 'application/json'},
                  body: JSON.stringify({damping: 9})}).then(function (r) { done(r.status); });
        """)

        d.get(base + "/login")
        d.find_element(By.ID, "password").send_keys(a.password)
        d.find_element(By.CSS_SELECTOR, ".login-form button").click()
        wait("the plant after login", lambda: "Log out" in d.find_element(By.TAG_NAME, "header").text, 20)
        d.get(base + "/device/1")
        damping = d.find_element(By.CSS_SELECTOR, '#form-damping input[name="damping"]')
        damping.clear()
        damping.send_keys("1.7")
        d.find_element(By.CSS_SELECTOR, "#form-damping button").click()
        banner = wait("the write's result", lambda: d.find_element(By.ID, "banner"), 30)
        result["write_banner"] = banner.text
        result["write_ok"] = "ok" in banner.get_attribute("class").split()
        result["damping_now"] = d.find_element(By.CSS_SELECTOR, '#form-damping input[name="damping"]').get_attribute("value")
        d.execute_script("window.scrollTo(0, 0)")
        d.save_screenshot(os.path.join(a.shots, "device-write.png"))

        d.get(base + "/traffic")
        rows = wait("traffic frames", lambda: len(d.find_elements(By.CSS_SELECTOR, "#traffic tbody tr")) >= 6 and
                    len(d.find_elements(By.CSS_SELECTOR, "#traffic tbody tr")), 20)
        result["traffic_rows"] = rows
        result["download"] = d.find_element(By.ID, "download").get_attribute("href")
        d.save_screenshot(os.path.join(a.shots, "traffic.png"))
        logs = [e for e in d.get_log("browser") if e.get("level") == "SEVERE"] if hasattr(d, "get_log") else []
        # The refused write above is the one error expected.
        result["console_errors"] = [e.get("message") for e in logs
                                    if "/api/devices/1/write" not in e.get("message", "")]
    finally:
        d.quit()
    print(json.dumps(result))


if __name__ == "__main__":
    sys.exit(main())
