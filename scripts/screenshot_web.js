// Screenshot of the Rerun web viewer in headless Chromium: the browser check of `make view`.
//
// Not part of `make test` (CI has no browser). For developers, with Debian's chromium and
// puppeteer-core installed outside the repository:
//
//   apt-get install -y chromium
//   npm install --prefix ~/tools/puppeteer puppeteer-core
//   make view &                       # or VIEW_GRPC_PORT=... VIEW_WEB_PORT=... make view
//   NODE_PATH=~/tools/puppeteer/node_modules node scripts/screenshot_web.js \
//     'http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy' view.png
//
// Chromium renders WebGPU/WebGL in software (SwiftShader); the viewer's wasm takes about
// 20 s to load that way, hence the wait (third argument, seconds; default 25).
'use strict';
const puppeteer = require('puppeteer-core');

async function main() {
  const [url, output, waitSeconds = '25'] = process.argv.slice(2);
  if (!url || !output) {
    console.error('usage: screenshot_web.js URL OUTPUT.png [WAIT_SECONDS]');
    process.exit(2);
  }
  const browser = await puppeteer.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    headless: true,
    args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
           '--window-size=1600,900'],
  });
  try {
    const page = await browser.newPage();
    await page.setViewport({width: 1600, height: 900});
    page.on('pageerror', (error) => console.error(`page error: ${error.message}`));
    await page.goto(url, {waitUntil: 'load', timeout: 60000});
    await new Promise((resolve) => setTimeout(resolve, Number(waitSeconds) * 1000));
    await page.screenshot({path: output});
    console.log(`wrote ${output}`);
  } finally {
    await browser.close();
  }
}

main().catch((error) => {
  console.error(`screenshot_web: ${error.message}`);
  process.exit(1);
});
