// Screenshots of the Rerun web viewer in headless Chromium: the browser check of `make view`.
//
// Not part of `make test` (CI has no browser). For developers, with Debian's chromium and
// puppeteer-core installed outside the repository:
//
//   apt-get install -y chromium
//   npm install --prefix ~/tools/puppeteer puppeteer-core
//   make view &                       # or VIEW_GRPC_PORT=... VIEW_WEB_PORT=... make view
//   NODE_PATH=~/tools/puppeteer/node_modules node scripts/screenshot_web.js \
//     'http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy' view 10,25,40
//
// writes view-10s.png, view-25s.png and view-40s.png: the page 10, 25 and 40 s after it
// loaded (default 25: Chromium renders WebGPU/WebGL in software, SwiftShader, and the
// viewer's wasm takes about 20 s to load that way). For each it prints one line with the
// wall-clock times (seconds since the epoch) when the shot was asked for and when it was
// taken (a busy page takes a while to draw it), to compare the simulated time the page shows
// with the node's then (`make soak ARGS=liveview` does). THEME=dark or THEME=light sets the
// colour scheme the page sees (the viewer follows it).
'use strict';
const puppeteer = require('puppeteer-core');

async function main() {
  const [url, prefix, times = '25'] = process.argv.slice(2);
  const seconds = times.split(',').map(Number);
  if (!url || !prefix || seconds.some((s) => !(s >= 0))) {
    console.error('usage: screenshot_web.js URL OUTPUT_PREFIX [SECONDS,SECONDS,...]');
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
    // THEME=dark or light: the viewer follows the system's colour scheme.
    if (process.env.THEME) {
      await page.emulateMediaFeatures([{name: 'prefers-color-scheme', value: process.env.THEME}]);
    }
    page.on('pageerror', (error) => console.error(`page error: ${error.message}`));
    // Every request that leaves this machine: what an offline lab would see fail.
    page.on('request', (request) => {
      const host = new URL(request.url()).hostname;
      if (!['127.0.0.1', 'localhost'].includes(host) && !request.url().startsWith('data:')) {
        console.log(`off-machine request: ${request.method()} ${request.url()}`);
      }
    });
    page.on('requestfailed', (request) => {
      console.log(`failed request: ${request.url()} (${request.failure().errorText})`);
    });
    await page.goto(url, {waitUntil: 'load', timeout: 60000});
    const loaded = Date.now();
    console.log(`loaded ${loaded / 1000}`);
    for (const after of [...seconds].sort((a, b) => a - b)) {
      const wait = loaded + after * 1000 - Date.now();
      if (wait > 0) {
        await new Promise((resolve) => setTimeout(resolve, wait));
      }
      const output = `${prefix}-${after}s.png`;
      const started = Date.now();
      await page.screenshot({path: output});
      console.log(`${output} ${started / 1000} ${Date.now() / 1000}`);
    }
  } finally {
    await browser.close();
  }
}

main().catch((error) => {
  console.error(`screenshot_web: ${error.message}`);
  process.exit(1);
});
