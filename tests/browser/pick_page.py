#!/usr/bin/python3
"""Drives `geostride gcp pick`'s page in headless Chromium as a person would (tests/gcp_pick.rs):
open it, zoom with the wheel, drag one pick, reject one, accept one, try to save over an input,
save, screenshot, quit. Prints what it did and saw as JSON for the Rust test to check against the
saved CSV.

usage: pick_page.py URL --move NAME --reject NAME --accept NAME --input PATH --save PATH
                    --screenshot PNG
"""

import argparse
import json
import sys
import time

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.actions.wheel_input import ScrollOrigin
from selenium.webdriver.common.by import By
from selenium.common.exceptions import StaleElementReferenceException


def wait_for(driver, script, what, timeout=30.0):
    end = time.time() + timeout
    while time.time() < end:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.05)
    raise SystemExit(f"timed out waiting for {what}")


def click_row(driver, name):
    """Clicks a point's row; the table is redrawn after every fit, so a row found may be gone."""
    for _ in range(20):
        try:
            driver.find_element(By.CSS_SELECTOR, f"tr[data-name='{name}']").click()
            return
        except StaleElementReferenceException:
            time.sleep(0.05)
    raise SystemExit(f"the row of {name} kept being redrawn")


def page_state(driver):
    return driver.execute_script(
        "const S = window.pickPage.S;"
        "return {scale: S.scale, fits: S.fits, sel: S.sel,"
        " picks: Array.from(S.picks, ([k, p]) => [k.split('\\u0000')[1], p.u, p.v, p.status])};"
    )


def pick(state, name):
    for n, u, v, status in state["picks"]:
        if n == name:
            return u, v, status
    raise SystemExit(f"no pick of {name} on the page")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("url")
    for a in ("--move", "--reject", "--accept", "--input", "--save", "--screenshot"):
        ap.add_argument(a, required=True)
    args = ap.parse_args()

    options = webdriver.ChromeOptions()
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              "--window-size=1280,800", "--force-device-scale-factor=1"):
        options.add_argument(a)
    options.binary_location = "/usr/bin/chromium"
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    seen = {}
    try:
        driver.get(args.url)
        wait_for(driver, "return document.body.dataset.ready === '1' && +document.body.dataset.fits >= 1",
                 "the page to load and fit")
        canvas = driver.find_element(By.ID, "view")
        before = page_state(driver)
        seen["scale_before"] = before["scale"]
        seen["fit_message_before"] = driver.find_element(By.ID, "fitmsg").text

        # Zoom: the wheel over the canvas.
        ActionChains(driver).scroll_from_origin(ScrollOrigin.from_element(canvas), 0, -600).perform()
        wait_for(driver, f"return window.pickPage.S.scale > {before['scale'] * 1.5}", "the zoom")
        seen["scale_after"] = page_state(driver)["scale"]

        # Move: select the point in the list (the view centres on it), drag its cross.
        click_row(driver, args.move)
        state = page_state(driver)
        u0, v0, _ = pick(state, args.move)
        xy = driver.execute_script(
            "const r = document.getElementById('view').getBoundingClientRect();"
            f"const [x, y] = window.pickPage.toScreen({u0}, {v0});"
            "return [r.left + x, r.top + y];"
        )
        fits = state["fits"]
        drag = ActionChains(driver)
        drag.w3c_actions.pointer_action.move_to_location(int(round(xy[0])), int(round(xy[1])))
        drag.w3c_actions.pointer_action.pointer_down()
        for k in range(1, 6):
            drag.w3c_actions.pointer_action.move_to_location(int(round(xy[0])) + 6 * k,
                                                             int(round(xy[1])) + 4 * k)
        drag.w3c_actions.pointer_action.pointer_up()
        drag.perform()
        wait_for(driver, f"return window.pickPage.S.fits > {fits}", "the fit after the move")
        state = page_state(driver)
        u1, v1, status = pick(state, args.move)
        seen["moved"] = {"name": args.move, "u0": u0, "v0": v0, "u1": u1, "v1": v1,
                         "status": status, "scale": state["scale"]}

        # Reject one and accept another from the keyboard.
        for name, k in ((args.reject, "r"), (args.accept, "a")):
            click_row(driver, name)
            ActionChains(driver).send_keys(k).perform()
        state = page_state(driver)
        seen["rejected"] = pick(state, args.reject)[2]
        seen["accepted"] = pick(state, args.accept)[2]
        seen["table"] = driver.find_element(By.ID, "points").text
        wait_for(driver, "return !!window.pickPage.S.fit && window.pickPage.S.fit.fitted", "a fit")
        seen["fit_message"] = driver.find_element(By.ID, "fitmsg").text

        # Saving over an input is refused, with a message on the page.
        path = driver.find_element(By.ID, "path")
        path.clear()
        path.send_keys(args.input)
        driver.find_element(By.ID, "save").click()
        seen["refusal"] = wait_for(driver, "return document.body.dataset.saveError", "the refusal")

        path.clear()
        path.send_keys(args.save)
        driver.find_element(By.ID, "save").click()
        seen["saved"] = wait_for(driver, "return document.body.dataset.saved", "the save")
        seen["message"] = driver.find_element(By.ID, "message").text

        # The screenshot: the whole image, the loupe on the target the pick was moved off.
        click_row(driver, args.move)
        ActionChains(driver).send_keys("0").perform()
        xy = driver.execute_script(
            "const r = document.getElementById('view').getBoundingClientRect();"
            f"const [x, y] = window.pickPage.toScreen({u0}, {v0});"
            "return [r.left + x, r.top + y];"
        )
        hover = ActionChains(driver)
        hover.w3c_actions.pointer_action.move_to_location(int(round(xy[0])), int(round(xy[1])))
        hover.perform()
        driver.save_screenshot(args.screenshot)

        driver.find_element(By.ID, "quit").click()
        wait_for(driver, "return document.getElementById('message').textContent.includes('ended')",
                 "the quit")
    finally:
        driver.quit()
    json.dump(seen, sys.stdout)


if __name__ == "__main__":
    main()
